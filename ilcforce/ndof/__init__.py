"""The nominal task-space model of eq. (4) in n dimensions (``algebra``), which the loop (``ilcforce.loop``) and the
MuJoCo cross-check's sampler write into a law's measurement vector."""
