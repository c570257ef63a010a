"""The solvers of every model: the contracts a run drives (`contract`), the choice by name
(`by_name`), a load step between model and solver (`step`); the static Newton reference
(`static`, its backends `newton_backend`, `newton_banded`, `newton_sparse`, `newton_info`,
its friction strategies `friction_chain` and `active_set`, its linear algebra `banded` and
`ldlt`, its `certificate`) and the dynamic solver on the Warp kernels (`dynamic`)."""
