"""Comparison reports: the sweep of training runs (sweep), the baseline controllers (controllers),
the paired evaluation of every method on the same states (paired), the report (report) and its
plots (plots).

    from asap_dsl.backends.compare import compare
"""

from .controllers import GreedyController, LookaheadController, OracleController, candidate_actions, lookahead_problem
from .paired import CompareResult, compare
from .report import Column, Method, ReportData, markdown, write
from .sweep import Job, JobResult, SweepInterrupted, execute, plan

__all__ = ["Column", "CompareResult", "GreedyController", "Job", "JobResult", "LookaheadController", "Method",
           "OracleController", "ReportData", "SweepInterrupted", "candidate_actions", "compare", "execute",
           "lookahead_problem", "markdown", "plan", "write"]
