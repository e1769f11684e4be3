"""The collapsed posterior sampler (emcee over the sensor parameters, each point
integrated out), its steps and moves, the floor-plan sampler, and the
independent full-joint NUTS reference (optional ``nuts`` extra).

See ``docs/architecture.md`` for the layers and what each may import.
"""
