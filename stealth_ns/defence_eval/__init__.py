"""``stealth-ns defend``: can the poison be found, and what does removing it cost?

:mod:`~stealth_ns.defence_eval.evaluate` (the run under defence, rendering after pruning, the defeat rule),
:mod:`~stealth_ns.defence_eval.command` (every defence, defend.json), :mod:`~stealth_ns.defence_eval.outputs`
(defend.md and the figures), :mod:`~stealth_ns.defence_eval.input_filter_retrain` (the input-filter
defence's retraining). The defences themselves are :mod:`stealth_ns.defences`. docs/design/defences.md.
"""
