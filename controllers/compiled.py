"""CasADi functions evaluated from numpy without per-call conversions: the flight software's compiled maths.

A CasADi ``Function`` built once from symbolic (SX) expressions runs in CasADi's
virtual machine, in C; :class:`Buffered` calls it on preallocated numpy arrays
(``Function.buffer``), so one call costs a few microseconds of Python however
large the expression. The NMPC's QP data and the UKF's sigma-point propagation
are evaluated this way (``controllers.guidance.nmpc``, ``controllers.estimation.ukf``).

Against numpy the results differ by rounding only (the same operations, in
CasADi's order): ``tests/test_ukf.py`` checks the UKF's against its numpy form.
"""
from __future__ import annotations

import casadi as ca
import numpy as np

__all__ = ["Buffered"]


class Buffered:
    """A CasADi Function evaluated on preallocated numpy arrays (``Function.buffer``: no DM conversions).

    ``inputs[i]`` / ``outputs[i]`` hold the nonzeros (column-major) of input/output i; a call copies its
    arguments into them (None: left as it stands, so a caller may write an input in place and call with no
    arguments) and evaluates. ``rebind``: bind the arrays again before each evaluation and zero the outputs
    (the QP plugins consume the output pointers on evaluation and accumulate into them; 15 us).
    """

    def __init__(self, f: ca.Function, rebind: bool = False):
        self.f = f
        self.rebind = rebind
        self.inputs = [np.zeros(f.nnz_in(i)) for i in range(f.n_in())]
        self.outputs = [np.zeros(f.nnz_out(i)) for i in range(f.n_out())]
        self.buf, self._eval = f.buffer()
        self._bind()

    def _bind(self) -> None:
        for i, a in enumerate(self.inputs):
            self.buf.set_arg(i, memoryview(a))
        for i, r in enumerate(self.outputs):
            self.buf.set_res(i, memoryview(r))

    def __call__(self, *args) -> list[np.ndarray]:
        for dst, src in zip(self.inputs, args):
            if src is not None:
                dst[:] = src
        if self.rebind:
            for r in self.outputs:
                r.fill(0.0)
            self._bind()
        self._eval()
        return self.outputs

    def stats(self) -> dict:
        return self.buf.stats()
