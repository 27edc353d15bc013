"""The two papers' protocols: the coupled 3-DOF study (paper 000, :mod:`pipeline.studies.coupled`, stages tune and
train) and the decoupled damping study (paper 001, :mod:`pipeline.studies.decoupled`, stage decoupled)."""
