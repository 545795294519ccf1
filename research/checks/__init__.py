"""Registered gradient checks (see research.gradcheck.register_check).

Each module here is listed in research.registry.GRADCHECK_MODULES; importing it
registers its checks. `drlab gradcheck` runs them all and prints one table.
"""
