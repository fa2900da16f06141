"""File formats other stages and packages share: the BOP dataset format (``bop``) and instance overlays
(``drawing``)."""
