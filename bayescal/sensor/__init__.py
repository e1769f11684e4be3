"""The sensor model of the paper: the eight parameters and their identifiable
combinations, the camera (eq. 1: projection and back-projection), the laser cone
(eqs. 3-6) and triangulation, with their Jacobians. Imports nothing above it.

See ``docs/architecture.md`` for the layers and what each may import.
"""
