"""drlab's experiments, one module each (research.experiment's contract; registered in research.registry).

Run one with `drlab run NAME`, `python -m experiments.NAME` or `python experiments/NAME.py`.
"""
