"""``matrix-field-qp``: the matrix-field planner with each step solved as one quadratic program
(docs/method.md, section 5), joint position and velocity limits as hard constraints.

Modules: ``config`` (settings), ``formulation`` (the QP of a step from the matrix-field task
terms), ``solve`` (qpsolvers backends, timing, named failures), ``planner`` (the step in the
shared IK loop).
"""

from planbench_plugins.matrix_field_qp.config import MatrixFieldQPConfig, installed_solvers
from planbench_plugins.matrix_field_qp.formulation import StepQP
from planbench_plugins.matrix_field_qp.planner import MatrixFieldQPPlanner
from planbench_plugins.matrix_field_qp.solve import QPFailure, QPSolver

__all__ = ["MatrixFieldQPConfig", "MatrixFieldQPPlanner", "QPFailure", "QPSolver", "StepQP", "installed_solvers"]
