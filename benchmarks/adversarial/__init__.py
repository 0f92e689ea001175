"""Categories of adversarial cases for ``benchmarks/bench_adversarial.py`` (see tally.py)."""
