"""The contract between the two simulators: the scenario's settings (`config`,
its strict YAML `loader`), the edges' ids (`edges`), the demand schedules drawn
from it (`schedule`) and the record of a run (`records`). Imports nothing else
of jaxround."""
