"""What a rule reports (:class:`Finding`) and its conversion to and from UsdValidation errors and
JSON.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field

import numpy as np

from usdahd.usd import validation as usd_validation
from usdahd.validate.registry import PLUGIN_NAME

__all__ = [
    "FINDING_DATA",
    "Finding",
    "RuleFindings",
    "SkipRule",
    "dumps",
    "finding_from_usd",
    "findings_json",
    "jsonable",
]

# --------------------------------------------------------------------------------- findings


@dataclass
class Finding:
    """One result of a rule on a prim.

    rule : a RULE_NAMES entry; severity : error, warning or info; prim : prim path;
    code : short machine name of the defect (the UsdValidation error name); message : what is
    wrong, ending with what to do; data : numbers behind the message (JSON-serialisable).
    """

    rule: str
    severity: str
    prim: str
    code: str
    message: str
    data: dict = field(default_factory=dict)

    def to_usd(self, stage):
        """The ``UsdValidation.ValidationError`` of this finding on ``stage``."""
        return usd_validation.to_error(self, stage)


class RuleFindings:
    """Collects findings of one rule on one prim."""

    def __init__(self, rule: str, prim):
        self.rule, self.prim, self.out = rule, str(prim.GetPath()), []

    def add(self, severity: str, code: str, message: str, fix: str = "", **data):
        text = message.rstrip(".") + "." + (f" Fix: {fix.rstrip('.')}." if fix else "")
        self.out.append(Finding(self.rule, severity, self.prim, code, text, jsonable(data)))

    def error(self, code, message, fix="", **data):
        self.add("error", code, message, fix, **data)

    def warning(self, code, message, fix="", **data):
        self.add("warning", code, message, fix, **data)

    def info(self, code, message, fix="", **data):
        self.add("info", code, message, fix, **data)

    def skipped(self, why) -> None:
        """The info finding ``Skipped``: "<rule> did not run: <why>"."""
        self.info("Skipped", f"{self.rule} did not run: {why}")


def jsonable(d: dict) -> dict:
    out = {}
    for k, v in d.items():
        if isinstance(v, np.generic):
            v = v.item()
        if isinstance(v, float) and not math.isfinite(v):
            v = str(v)
        if isinstance(v, tuple | np.ndarray):
            v = np.asarray(v).tolist()
        out[k] = v
    return out


class SkipRule(Exception):
    """Prerequisite data missing; another rule reports why (becomes an info finding)."""


#: (rule, prim, code, message) -> data of findings returned through UsdValidation, which can
#: only carry a message; ``usdahd validate --json`` adds the numbers back from here.
FINDING_DATA: dict = {}


def finding_from_usd(error) -> Finding:
    """A Finding from a UsdValidation.ValidationError (ours or a built-in validator's)."""
    vname, sev, prim, code, msg = usd_validation.error_record(error)
    rule = vname.split(":", 1)[1] if vname.startswith(PLUGIN_NAME + ":") else vname
    return Finding(rule, sev, prim, code, msg, dict(FINDING_DATA.get((rule, prim, code, msg), {})))


def findings_json(findings: list[Finding]) -> list[dict]:
    return [
        {
            "rule": f.rule,
            "severity": f.severity,
            "prim": f.prim,
            "code": f.code,
            "message": f.message,
            "data": f.data,
        }
        for f in findings
    ]


def dumps(findings: list[Finding]) -> str:
    return json.dumps(findings_json(findings), indent=2, sort_keys=True)
