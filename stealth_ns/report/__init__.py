"""``stealth-ns report``: a poisoned run against a clean run of the same scene.

:mod:`~stealth_ns.report.success` (the paper's success rule), :mod:`~stealth_ns.report.numbers` (the
numbers of a pair of runs), :mod:`~stealth_ns.report.write` (report.json, the pictures, the command),
:mod:`~stealth_ns.report.html` (report.html), :mod:`~stealth_ns.report.defences_section` (a
``stealth-ns defend`` folder as the report's "Defences" section).
"""
