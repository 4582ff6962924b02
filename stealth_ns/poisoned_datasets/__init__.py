"""Dataset poisoning: poisoned copies of datasets (the data-only StealthAttack, IPA-Splat)."""
