"""The solvers of every model: the contracts a run drives (`contract`), the choice by name
(`by_name`); the static Newton reference (`static`, its backends `newton_backend`,
`newton_banded`, `newton_sparse`, `newton_info`, its friction strategies `friction_chain`
and `active_set`, its `certificate`) and the dynamic solver on the Warp kernels
(`dynamic`). Their linear algebra is `dynfab.linalg`; a load step's start and solution,
which models and solvers exchange, `dynfab.model.step`."""
