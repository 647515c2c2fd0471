"""Many runs: batch specs, dispersions, generated cases; a process pool or a Ray cluster.

The package is callable: ``fwsim.batch(spec, ...)`` is :func:`fwsim.sim.api.batch` even once a module of this
package is imported (the import puts the package where ``fwsim`` exports the function).
"""
import sys


class _CallableModule(type(sys)):
    def __call__(self, *args, **kwargs):
        from fwsim.sim.api import batch
        return batch(*args, **kwargs)


sys.modules[__name__].__class__ = _CallableModule
