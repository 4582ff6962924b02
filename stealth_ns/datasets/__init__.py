"""Datasets the tools train on: what a dataset folder holds (:mod:`~stealth_ns.datasets.source`), seed
points made once for a folder without them (:mod:`~stealth_ns.datasets.seeded`) and generated scenes made
once (:mod:`~stealth_ns.datasets.generated`). Below both the poisoning commands and the bench; its
checks of seed points (:mod:`~stealth_ns.datasets.seed_check`) and of the files a transforms file names
(:mod:`~stealth_ns.datasets.references`) are below :mod:`stealth_ns.datasets.check`.
"""
