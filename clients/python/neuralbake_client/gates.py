"""Quality gates of a build: one comparison of a metric of an artifact's manifest against a number, or
against the same metric of the previous build's artifact (a regression gate):

    flip <= 0.1                      the model's FLIP against the converged reference
    worse_than_one_spp == 0          never worse than 1-spp path tracing (1 is worse)
    flip <= previous + 0.01          not more than 0.01 worse than the last accepted build
    relative_mse <= previous * 1.1   not more than 10% worse

A regression gate of an item that has no previous build passes, and says so.
"""

from __future__ import annotations

import operator
import re
from collections.abc import Callable, Mapping
from dataclasses import dataclass

from pydantic import BaseModel

OPERATORS: dict[str, Callable[[float, float], bool]] = {
    "<=": operator.le,
    "<": operator.lt,
    ">=": operator.ge,
    ">": operator.gt,
    "==": operator.eq,
    "!=": operator.ne,
}
NUMBER = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?"
GATE = re.compile(
    rf"^\s*(?P<metric>[A-Za-z_][A-Za-z0-9_.]*)\s*(?P<op><=|>=|==|!=|<|>)\s*"
    rf"(?:(?P<previous>previous)\s*(?:(?P<shift>[-+*])\s*(?P<by>{NUMBER}))?|(?P<value>{NUMBER}|true|false))\s*$"
)
BOOLEANS = {"true": 1.0, "false": 0.0}  # the manifest stores flags as 1.0 / 0.0


class GateError(ValueError):
    """A gate that does not parse; the message shows the accepted forms."""


class GateResult(BaseModel):
    gate: str
    passed: bool
    value: float | None = None  # the metric's value in this build (None: the manifest lacks it)
    threshold: float | None = None  # what it was compared with (None: no previous build)
    note: str = ""


@dataclass(frozen=True)
class Gate:
    text: str
    metric: str
    op: str
    value: float | None  # a fixed threshold, or None for a regression gate
    shift: str | None = None  # regression gates: "+", "-" or "*" applied to the previous value
    by: float = 0.0

    @classmethod
    def parse(cls, text: str) -> Gate:
        match = GATE.match(text)
        if match is None:
            raise GateError(
                f"gate {text!r}: write METRIC OP NUMBER (e.g. `flip <= 0.1`) or METRIC OP previous "
                f"[+-* NUMBER] (e.g. `flip <= previous + 0.01`), OP one of {' '.join(OPERATORS)}"
            )
        raw = match["value"]
        value = None if raw is None else BOOLEANS[raw] if raw in BOOLEANS else float(raw)
        return cls(
            text.strip(), match["metric"], match["op"], value, match["shift"], float(match["by"] or 0.0)
        )

    @property
    def regression(self) -> bool:
        return self.value is None

    def threshold(self, previous: Mapping[str, float] | None) -> float | None:
        if not self.regression:
            return self.value
        if previous is None or self.metric not in previous:
            return None
        base = previous[self.metric]
        return {"+": base + self.by, "-": base - self.by, "*": base * self.by, None: base}[self.shift]

    def check(self, metrics: Mapping[str, float], previous: Mapping[str, float] | None) -> GateResult:
        """The gate on this build's `metrics`, against the `previous` build's when it is a regression gate."""
        value = metrics.get(self.metric)
        if value is None:
            known = ", ".join(sorted(metrics)) or "none"
            return GateResult(gate=self.text, passed=False, note=f"no metric {self.metric!r} (has: {known})")
        threshold = self.threshold(previous)
        if threshold is None:
            return GateResult(gate=self.text, passed=True, value=value, note="no previous build to compare")
        passed = OPERATORS[self.op](value, threshold)
        return GateResult(gate=self.text, passed=passed, value=value, threshold=threshold)
