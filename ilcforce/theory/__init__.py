"""Theory beside the simulation: the lifted-system check of a learning law (:mod:`ilcforce.theory.lifted`)
and its validation against long runs (:mod:`ilcforce.theory.validation`, ``make lifted``), and the lifted
model of the nominal closed loop a norm-optimal ILC learns on (:mod:`ilcforce.theory.norm_optimal`)."""
