"""The applications: the command line (`cli`), the main job (`pipeline`),
parity with SUMO, the benchmark, the headroom study."""
