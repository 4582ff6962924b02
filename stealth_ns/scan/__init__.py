"""``stealth-ns scan``: poison in a 3DGS model from any trainer, found without poison tags
(docs/design/scan.md)."""
