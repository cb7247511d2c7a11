"""The n-joint simulation (docs/model.md#n-dof): the compiled loop for a robot whose joint count is not 2
(``loop``), its small dense algebra and eq. (4) (``algebra``), tau_d along the path (``desired``)."""
