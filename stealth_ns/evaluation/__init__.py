"""Evaluation: the attack report, the KDE difficulty protocol and the experiment runner."""
