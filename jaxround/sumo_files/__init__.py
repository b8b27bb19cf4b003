"""SUMO's files: building a network with netconvert (`netconvert`), finding the
SUMO binaries (`binaries`), compiling a `.net.xml` into the core's arrays
(`compile`). Both the JAX side and `sumo_export` use it."""
