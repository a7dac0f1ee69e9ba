"""Analytic gradients of MuJoCo-Warp's step (``--backend-option gradients=adjoint``): one MuJoCo
step recomputed in torch at the engine's own states and differentiated there (:mod:`.step`)."""
