"""The `pegasus` command line: one module per command group (thin shells over the library) and shared flags.
The only composition root: the one place in pegasus_gen that imports dope_training, robot_bridge and nodes."""
