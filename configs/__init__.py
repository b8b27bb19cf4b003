"""Built-in scenario and training configurations (YAML files beside this module)."""
