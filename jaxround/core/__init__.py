"""The simulation core: pure JAX functions over fixed-size vehicle arrays.

Types (`state`, `network`), car following (`idm`, `finalize`), who is where
(`geometry`, `neighbours`, `link_leaders`), the junction (`junction`),
insertion, emissions, TraCI speed commands (`command`) and the step's
planning (`dynamics`). No I/O, no SUMO, no training: it imports only
`jaxround.scenario` (for the types of the settings) besides itself.
"""
