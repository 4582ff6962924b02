"""Foundations every layer uses: the one error type, JSON and whole-or-nothing writes, output folders
and their file manifests, dataset fingerprints, provenance, figures and HTML pages, thread-invariant
activations, malloc settings and step timing. Nothing here imports another package of stealth_ns."""
