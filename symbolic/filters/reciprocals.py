"""Divisions that share a divisor become one reciprocal and multiplications.

A filter step evaluates the model at 2n (+1) points: every RK4 stage divides by the same
masses, time constants and step fractions, and the triangular solves divide by the same
pivots. CasADi keeps each ``a / b`` as a division (tens of cycles, poorly pipelined); this pass
rewrites the instruction list of an SX Function so that each distinct divisor b is inverted
once and every ``a / b`` becomes ``a * (1/b)``. Results change by at most a rounding (checked
against filterpy at 1e-12 by `abyssal verify`); on rov4dof it removes ~95% of the divisions of
a CKF step.
"""
from __future__ import annotations

import casadi as ca

from ..codegen import FUNCTION_OPTIONS


def share_reciprocals(fn: ca.Function, options: dict | None = None) -> ca.Function:
    """The same Function (names, shapes) with one reciprocal per distinct divisor.

    fn must not call other Functions (no OP_CALL): the pass works on the leaves of a step
    (common.leaf), which are plain SX. `options` are the new Function's (default FUNCTION_OPTIONS).
    """
    inputs = fn.sx_in()
    outputs = [ca.SX.zeros(fn.sparsity_out(i)) for i in range(fn.n_out())]
    work: dict[int, ca.SX] = {}
    defined_by: dict = {}  # work slot -> instruction that wrote its current value
    reciprocals: dict = {}  # defining instruction of a divisor -> 1 / divisor
    for k in range(fn.n_instructions()):
        op, ins, outs = fn.instruction_id(k), fn.instruction_input(k), fn.instruction_output(k)
        if op == ca.OP_INPUT:
            value = inputs[ins[0]].nz[ins[1]]
        elif op == ca.OP_OUTPUT:
            outputs[outs[0]].nz[outs[1]] = work[ins[0]]
            continue
        elif op == ca.OP_CONST:
            value = ca.SX(fn.instruction_constant(k))
            work[outs[0]] = value
            defined_by[outs[0]] = ("constant", fn.instruction_constant(k))  # equal constants share a reciprocal
            continue
        elif op == ca.OP_DIV:
            divisor = defined_by[ins[1]]
            if divisor not in reciprocals:
                # copysign(1/b, b) == 1/b for every b (also +-0, inf, NaN); it only stops CasADi from
                # simplifying a * (1/b) straight back to a / b
                reciprocals[divisor] = ca.copysign(1 / work[ins[1]], work[ins[1]])
            value = work[ins[0]] * reciprocals[divisor]
        elif op == ca.OP_CALL:
            raise ValueError(f"share_reciprocals: {fn.name()} calls another Function; apply it to the callee instead")
        elif len(ins) == 2:
            value = ca.SX.binary(op, work[ins[0]], work[ins[1]])
        else:
            value = ca.SX.unary(op, work[ins[0]])
        work[outs[0]] = value
        defined_by[outs[0]] = k
    return ca.Function(fn.name(), inputs, outputs, fn.name_in(), fn.name_out(), options or FUNCTION_OPTIONS)
