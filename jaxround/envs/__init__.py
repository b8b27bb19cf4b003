"""The RL environment on top of the core: the gymnax-form `RoundaboutEnv`
(`roundabout`), what AVs observe (`observe`), their rewards (`reward`),
what an action means (`assertiveness`), scripted controllers and rollouts."""
