"""The control layer: the paper's controller on the host, one control step of one episode.

* :mod:`~mcverify.control.decision`: Algorithm 1 (alg.framework) and the Conditions for Overtaking
  (Table I, tab.cons_for_overtaking): which problem drives the ego;
* :mod:`~mcverify.control.planner`: the dual TO-CBF-MPC planner (Q1 overtake, Q2 go back) or the
  MPC-DC baseline on the compiled solvers, with warm starts, held plans, the infeasibility memo and
  the fallback brake; a turn-back or a held plan on a presumed failure is confirmed by a full solve first;
* :mod:`~mcverify.control.episode_state`: one episode's memory and counters (mode, warm starts, the
  infeasibility memo) and the kinds of solver failure;
* :mod:`~mcverify.control.margins`: Theorem 5 graded, the signed room of a step's Q1 and Q2 solves.
"""
