"""What the loop (``ilcforce.loop``) and the MuJoCo cross-check's sampler compute in n dimensions beside the law: the
true plant pressed against the wall (``contact``) and the nominal task-space model of eq. (4) (``algebra``)."""
