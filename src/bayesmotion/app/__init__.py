"""The applications: the command-line interface, the demo and its HTML report."""
