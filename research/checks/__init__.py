"""Registered gradient checks (see research.gradcheck.register_check).

Each module here is the `checks` part of one family in research.registry.FAMILIES; importing it
registers its checks, named "<family>.<what>". `drlab gradcheck` runs them all and prints one table.
"""
