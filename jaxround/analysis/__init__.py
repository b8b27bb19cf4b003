"""Analysis and reports: metrics, paired comparisons, tables, plots, rendering,
traffic surveys, calibration and gradients of the demand."""
