"""The rule for asset names, in one place (light to import): an asset's name is the name of its folder in the
library, so no path separators, no "." or "..", no hidden (leading ".") or option-like (leading "-") names."""

from __future__ import annotations

import re

from pegasus_gen.errors import PegasusError

ASSET_NAME_PATTERN = r"^[A-Za-z0-9_][A-Za-z0-9_.-]*$"


def check_asset_name(name: str) -> str:
    """``name`` when it may name an asset (``ASSET_NAME_PATTERN``), else PegasusError."""
    if not isinstance(name, str) or not re.fullmatch(ASSET_NAME_PATTERN, name):
        raise PegasusError(f"asset name {name!r}: use letters, digits, '_', '.' and '-', starting with a letter, "
                           "digit or '_' (it names a folder of the library)")
    return name
