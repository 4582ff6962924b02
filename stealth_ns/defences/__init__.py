"""Defences against Gaussian-splatting poisoning: suspicion scores, detection metrics, pruning."""
