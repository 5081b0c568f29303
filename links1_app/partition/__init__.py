"""Root/node screen partitioning at run time (paper section 4): the root, its nodes and the
experiments. The strategies and the root's load model (eq. 4.1) are the core's
:mod:`links1.partition`; this package runs them on worker processes or a Dask cluster.

The root is the links1 process; the nodes are worker processes on this machine (the local
pool) or the workers of a Dask cluster. Nothing here imports mitsuba/drjit, and dask is
imported only when a Dask backend is used. See ``docs/partitioning.md``.

Modules
-------
runtime      what a node runs: renderer specs, one renderer per worker, culling
handout      how the root hands units out: tasks within a pixel budget, guided chunks
executors    the root's driver (assembly, checkpoint, progress, fault handling) and the
             in-process backend
local_pool   the local-pool backend: worker processes on this machine, their CPUs, deaths
dask_backend the Dask backend (existing cluster or a LocalCluster on 127.0.0.1)
checkpoint   finished units kept on disk
costmodel    the cost model fitted on units launched alone, the run's overheads, the reference
report       the schedule report of one run and where its makespan went
simulator    replaying plans with fitted costs for node counts this machine cannot run
plots        the report's and the simulation's figures (matplotlib)
cli          the distributed options of ``links1 render`` and the set-up ``links1 schedule`` shares
schedule     ``links1 schedule``: a real run (or a sweep), its report, simulation and plots
"""
