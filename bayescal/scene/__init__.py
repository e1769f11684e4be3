"""The scene: simulated rooms (``simulate_room``), the rough floor plan
(``FloorPlan``) and its corners.

See ``docs/architecture.md`` for the layers and what each may import.
"""
