"""The benchmark as data and its commands: the paper's experiment grid (`grid`), the results store
(`store`), `reproduce`, `report` (the results page), `bench` (score any policy on every paper suite)
and the paper's published numbers (`paper`). The world family records live in
`specrl_jax.families`, below every layer, so that worlds, methods and suites can read them."""
