"""The checks: gradients against finite differences and between engines, physics parity, speed,
solver settings, and the analyses of a trained policy (loss landscape, step gain). Each kind the
suite runs is declared once in :mod:`.kinds`."""
