"""The log-line budget that whatever a network client can make the appliance log goes through."""

from __future__ import annotations

from edge.log_budget import LogBudget


def test_at_most_so_many_lines_a_minute_and_the_next_line_says_how_many_were_left_out() -> None:
    budget = LogBudget(3)
    assert [budget.take(t) for t in (0.0, 1.0, 2.0, 3.0, 59.9)] == [True, True, True, False, False]
    assert budget.take(60.0)  # a new minute
    assert budget.left_out() == 2 and budget.left_out() == 0  # said once, in the line being written


def test_a_reset_starts_afresh() -> None:
    budget = LogBudget(1)
    assert budget.take(5.0) and not budget.take(6.0)
    budget.reset()
    assert budget.take(7.0) and budget.left_out() == 0
