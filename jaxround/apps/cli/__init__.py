"""The `jaxround` command line (`main`), one module per group of subcommands."""
