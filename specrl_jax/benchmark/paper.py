"""The SpecRLBench paper's published numbers as data (`data/paper_tables.yaml`): Tables 2
(finite suites) and 3 (infinite suites) and the multi-agent table, each number with where the
project found it quoted. Only quoted numbers are there; a missing entry means "not known".

    from specrl_jax.benchmark import paper
    paper.lookup("PointLTL0-v0", "zone/finite/ind", "genz", "eta_s")  # mean 0.98, std None
"""

from __future__ import annotations

import dataclasses
import functools
from pathlib import Path

import yaml

DATA = Path(__file__).resolve().parent / "data" / "paper_tables.yaml"
TABLES = ("2", "3", "multi-agent")
KEYS = ("table", "env", "suite", "method", "metric", "mean", "std", "source")


@dataclasses.dataclass(frozen=True)
class PaperNumber:
    table: str
    env: str
    suite: str
    method: str
    metric: str
    mean: float
    std: float | None
    source: str

    def text(self, digits: int = 2) -> str:
        return f"{self.mean:.{digits}f}" + ("" if self.std is None else f" ± {self.std:.{digits}f}")


def load(path: str | Path = DATA) -> tuple[PaperNumber, ...]:
    """Every entry of the data file, checked: known keys and tables, no number given twice."""
    return _load(str(path))


@functools.lru_cache(maxsize=4)
def _load(path: str) -> tuple[PaperNumber, ...]:
    entries = yaml.safe_load(Path(path).read_text()) or []
    numbers, seen = [], set()
    for i, entry in enumerate(entries):
        if set(entry) != set(KEYS):
            raise ValueError(f"{path}: entry {i} has keys {sorted(entry)}; expected {sorted(KEYS)}")
        if str(entry["table"]) not in TABLES:
            raise ValueError(f"{path}: entry {i}: unknown table {entry['table']!r}")
        number = PaperNumber(**{**entry, "table": str(entry["table"]),
                                "mean": float(entry["mean"]),
                                "std": None if entry["std"] is None else float(entry["std"])})
        key = (number.env, number.suite, number.method, number.metric)
        if key in seen:
            raise ValueError(f"{path}: {key} is given twice")
        seen.add(key)
        numbers.append(number)
    return tuple(numbers)


def lookup(env: str, suite: str, method: str, metric: str) -> PaperNumber | None:
    """The paper's number for (our env ID, suite, method, metric), or None if not quoted.
    A method variant (`ltl2action+bootcamp`) is compared with its method's number."""
    method = method.split("+")[0]
    for number in load():
        if (number.env, number.suite, number.method, number.metric) == (env, suite, method, metric):
            return number
    return None


def sources() -> list[str]:
    """The distinct sources of the numbers, in file order."""
    return list(dict.fromkeys(n.source for n in load()))
