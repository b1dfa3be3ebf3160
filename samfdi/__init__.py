"""The samfdi command-line application: wires sam, gsa, fdi and discrepancy together."""
