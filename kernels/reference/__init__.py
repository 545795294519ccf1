"""Plain NumPy references of every kernel family's forward pass, one module per family.

The tests check each Warp kernel against these; they favour clarity over speed.
"""
