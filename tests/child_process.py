"""The environment of a petsoft process a test spawns (the CLI, a script, `mpiexec -n 2 ...`)."""

import os


def child_env(**extra: str) -> dict[str, str]:
    """This process's environment, fit for a child that starts its own MPI job.

    MPI may run as root (these machines), ranks may oversubscribe the cores and yield when idle
    (busy-polling ranks on a shared 2-core machine crawl), matplotlib draws off-screen, and the
    variables of this process's own MPI singleton are dropped (a child inheriting them would
    join the wrong job).
    """
    env = dict(os.environ)
    env.update(OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1",
               OMPI_MCA_rmaps_base_oversubscribe="1", OMPI_MCA_mpi_yield_when_idle="1",
               MPLBACKEND="Agg", **extra)
    for k in list(env):
        if k.startswith(("OMPI_COMM_WORLD", "PMIX_", "OMPI_MCA_orte", "OMPI_MCA_ess")):
            env.pop(k)
    return env
