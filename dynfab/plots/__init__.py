"""Figures of a result file (`dynfab plot`): the look shared by every figure (`style`), a run's
figures (`figures`) and a shear specimen's (`specimen`)."""
