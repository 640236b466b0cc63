"""BenchMARL task files: ``Pan1Task.from_yaml(path)`` (see :mod:`pan1_env.benchmarl_task`)."""
