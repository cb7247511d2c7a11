"""Theory beside the simulation: the lifted-system check of a learning law (:mod:`ilcforce.theory.lifted`)
and its validation against long runs (:mod:`ilcforce.theory.validation`, ``make lifted``)."""
