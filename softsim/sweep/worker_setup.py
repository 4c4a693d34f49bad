"""Dask worker preload of ``local_client``'s workers: make their ``NUMBA_NUM_THREADS`` count.

The nanny puts ``NUMBA_NUM_THREADS`` into a worker's environment (its ``env``) only after the new
process has imported its parent's main module; the ``softsim`` command's main module imports
Numba, which reads the thread count it will launch with when imported.  Reading Numba's configuration again here, when
the worker starts and before anything has launched Numba's threads, makes the worker's own value
the one they launch with.

Why not the nanny's ``pre-spawn-environ``, which is there before the process starts: the nanny
writes those variables into its *own* process's environment at every worker (re)start and leaves
them there, so a restart during a sweep set ``NUMBA_NUM_THREADS`` in the client's process, and
that process's next compile stopped with "Cannot set NUMBA_NUM_THREADS to a different value
once the threads have been launched".
"""


def dask_setup(worker):
    import numba

    numba.config.reload_config()
