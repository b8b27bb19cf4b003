"""The SUMO side of jaxround: scenario files, the libsumo runner and evaluation."""
