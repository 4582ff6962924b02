"""Trained runs: loading one for evaluation (:mod:`~stealth_ns.runs.loaded`), a poisoned run paired
with the clean run of its scene (:mod:`~stealth_ns.runs.pair`), and training one with ``ns-train`` as
a subprocess (:mod:`~stealth_ns.runs.training`). Every command that consumes runs goes through here.
"""
