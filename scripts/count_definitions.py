#!/usr/bin/env python3
"""Counts of what the estimator defines more than once: the places each soil, torque-scale, usability,
curve-learner and observer setting is written, the places that list the records' statuses or reason codes, and the estimator settings a
user sets.

    scripts/count_definitions.py                    # the working tree
    scripts/count_definitions.py --rev b187f9a      # a commit (read with git show; no install needed)
    scripts/count_definitions.py --tree /tmp/base   # user settings of another checkout (imports it)

A place that defines a setting is one of: a pydantic / dataclass field (``name: T = ...`` in a class
body), a keyword of ``create_model`` (``name=(T, Field(...))``), a literal list, tuple or dict of three
or more setting names (``_CORE_FIELDS``, a name -> value dict handed to the core), and in Rust a struct
field (``pub name: f64``), an entry of a const name array, a ``get("name")`` of a hand-written
``from_map``, a ``name: 0.5`` of a hand-written ``defaults()``, or a ``settings_struct!`` declaration.
A place that defines the statuses or reasons lists four or more of their names (a Literal, a tuple, a
dict's keys, a const array of a Rust file).  A dataclass field made by ``from_core`` (its default and bounds
read from the core's declaration) uses a setting, it does not define it; a ``model_from_core`` model's own
fields count for its own group only (``torque_scale.enabled`` and ``curve.enabled`` are two settings).  The
settings counted are those the compiled core declares (``soilocp._core.settings_schema``) and the models' own
fields.
"""

from __future__ import annotations

import argparse
import ast
import re
import subprocess
import sys
from collections import Counter
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
GROUPS = ("soil", "torque_scale", "usability", "curve", "observer")


def files(rev: str | None, suffix: str, under: str) -> dict[str, str]:
    """path -> text of the files under ``under`` ending in ``suffix``, at ``rev`` or in the working tree."""
    if rev is None:
        return {str(p.relative_to(REPO)): p.read_text() for p in sorted((REPO / under).rglob(f"*{suffix}"))
                if "/target/" not in str(p)}
    names = subprocess.run(["git", "ls-tree", "-r", "--name-only", rev, under], cwd=REPO, capture_output=True,
                           text=True, check=True).stdout.split()
    return {n: subprocess.run(["git", "show", f"{rev}:{n}"], cwd=REPO, capture_output=True, text=True,
                              check=True).stdout for n in names if n.endswith(suffix) and "/target/" not in n}


def setting_names() -> dict[str, list[str]]:
    """group -> the setting names counted: the core's declarations and the Python models' own fields (the
    current tree's: a commit's count looks for the same names)."""
    from soilocp import _core
    from soilocp.estimation.soil_config import SoilConfig
    from soilocp.estimation.curve_config import CurveConfig
    from soilocp.estimation.observer_config import ObserverConfig
    from soilocp.estimation.torque_scale_config import TorqueScaleConfig
    from soilocp.estimation.wheel_usability import UsabilityLimits

    out = {}
    for group, model in zip(GROUPS, (SoilConfig, TorqueScaleConfig, UsabilityLimits, CurveConfig, ObserverConfig)):
        names = [n for n, *_ in _core.settings_schema(group)]
        out[group] = names + [n for n in model.model_fields if n not in names]
    return out


def _strings(node: ast.AST) -> list[str]:
    """The string constants a literal collection lists (for a tuple of pairs, each pair's first)."""
    if isinstance(node, (ast.Tuple, ast.List, ast.Set)):
        elts = node.elts
    elif isinstance(node, ast.Dict):
        elts = [k for k in node.keys if k is not None]
    else:
        return []
    out = []
    for e in elts:
        if isinstance(e, ast.Tuple) and e.elts:
            e = e.elts[0]
        if isinstance(e, ast.Constant) and isinstance(e.value, str):
            out.append(e.value)
    return out


def _from_core(value: ast.AST | None) -> bool:
    """A field's value that reads the core's declaration (``from_core(group, name)``)."""
    return isinstance(value, ast.Call) and getattr(value.func, "id", "") == "from_core"


def python_places(text: str, names: set[str], group: str | None = None) -> Counter:
    places: Counter = Counter()
    for node in ast.walk(ast.parse(text)):
        found: list[str] = []
        if isinstance(node, ast.ClassDef):  # a settings model: a class with three or more of the fields
            found = [st.target.id for st in node.body if isinstance(st, ast.AnnAssign)
                     and isinstance(st.target, ast.Name) and st.target.id in names and not _from_core(st.value)]
        elif isinstance(node, ast.Call) and getattr(node.func, "id", "") in ("create_model", "model_from_core"):
            of = node.args[1].value if len(node.args) > 1 and isinstance(node.args[1], ast.Constant) else None
            if group is None or of is None or of == group:  # a model's own fields, however few
                places.update(kw.arg for kw in node.keywords if kw.arg in names)
            continue
        else:
            found = list({s for s in _strings(node) if s in names})
        if len(set(found)) >= 3:
            places.update(found)
    return places


def rust_places(text: str, names: set[str]) -> Counter:
    """Each pattern's hits in a file where it names three or more of the settings (a struct, a name
    array, a from_map, a defaults(), a declaration block)."""
    places: Counter = Counter()
    for pat in (r"^\s*pub (\w+): f64,", r'^\s*"(\w+)",\s*$', r'get\("(\w+)"',
                r"^\s*(\w+): -?[0-9][0-9._]*(?: \* [0-9._]+)?,\s*$", r"^\s*(\w+): (?:Float|Int|Choice) = "):
        hits = [m.group(1) for m in re.finditer(pat, text, flags=re.M) if m.group(1) in names]
        if len(set(hits)) >= 3:
            places.update(hits)
    return places


def setting_counts(rev: str | None) -> dict[str, Counter]:
    py = files(rev, ".py", "soilocp")
    rs = files(rev, ".rs", "soilocp/_core/src")
    out = {}
    for group, names in setting_names().items():
        c: Counter = Counter({n: 0 for n in names})
        for text in py.values():
            try:
                c.update(python_places(text, set(names), group))
            except SyntaxError:
                pass
        for path, text in rs.items():
            # a test module's maps and defaults are the tests' own, not definitions
            body = text.split("#[cfg(test)]")[0]
            c.update(rust_places(body, set(names)))
        out[group] = c
    return out


def code_lists(rev: str | None) -> list[str]:
    """The places that list four or more status or reason names (keyed tables included, marked)."""
    from soilocp import _core

    statuses = {n for n, *_ in _core.status_codes()}
    reasons = {n for n, *_ in _core.reason_codes()}
    keyed = ("soilocp/estimation/next_steps.py", "soilocp/services/ros2/messages.py")  # advice / level per code
    generated = "soilocp/schemas/codes.py"  # written from the core's tables; a test fails when they differ
    out = []
    for path, text in files(rev, ".py", "soilocp").items():
        for node in ast.walk(ast.parse(text)):
            s = set(_strings(node))
            for kind, known in (("statuses", statuses), ("reasons", reasons)):
                if len(s & known) >= 4:
                    out.append(f"{path}:{node.lineno} {kind}" + (" (keyed table)" if path in keyed else
                                                                 " (generated from the core)" if path == generated else ""))
    for path, text in files(rev, ".rs", "soilocp/_core/src").items():
        body = text.split("#[cfg(test)]")[0]
        alone = set(re.findall(r'^\s*"([a-z_]+)",\s*$', body, flags=re.M))
        decl = set(re.findall(r'= "([a-z_]+)", (?:Soil|Publisher|Ocp),', body))
        for kind, known in (("statuses", statuses), ("reasons", reasons)):
            if len(alone & known) >= 4 or len(decl & known) >= 4:
                out.append(f"{path} {kind}")
    return out


def user_settings(tree: str | None) -> tuple[int, int, int]:
    """(estimator settings, user settings, calibrated constants): PipelineConfig's leaves, and of them those a
    user sets (not declared internal, nor fitted by ``soilocp calibrate``).  ``tree``: import soilocp from that
    checkout instead."""
    code = (
        "import json, sys\n"
        "from soilocp.estimation.config import PipelineConfig\n"
        "from pydantic import BaseModel\n"
        "def leaves(m):\n"
        "    for name, f in m.model_fields.items():\n"
        "        a = f.annotation\n"
        "        subs = [t for t in (a, *getattr(a, '__args__', ())) if isinstance(t, type) and issubclass(t, BaseModel)]\n"
        "        if subs: yield from leaves(subs[0])\n"
        "        else: yield f\n"
        "fs = list(leaves(PipelineConfig))\n"
        "def aud(f): return f.json_schema_extra.get('audience', 'user') if isinstance(f.json_schema_extra, dict) else 'user'\n"
        "print(json.dumps([len(fs), sum(aud(f) == 'user' for f in fs), sum(aud(f) == 'calibration' for f in fs)]))\n")
    r = subprocess.run([sys.executable, "-c", code], cwd=tree or REPO, capture_output=True, text=True, check=True)
    import json

    total, user, calibrated = json.loads(r.stdout)
    return total, user, calibrated


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rev", help="count a commit's files (default: the working tree)")
    ap.add_argument("--tree", help="a checkout to import for the user-settings count (default: this one)")
    ap.add_argument("--verbose", action="store_true", help="every setting's count")
    args = ap.parse_args()
    where = args.rev or "working tree"
    for group, c in setting_counts(args.rev).items():
        hist = Counter(c.values())
        print(f"{where}: {group} settings: {len(c)}; places each is defined: "
              + ", ".join(f"{k} place{'s' if k != 1 else ''}: {v}" for k, v in sorted(hist.items()))
              + f"; most: {max(c.values())} ({', '.join(sorted(n for n, v in c.items() if v == max(c.values()))[:4])})")
        if args.verbose:
            print("  " + ", ".join(f"{n} {v}" for n, v in c.items()))
    lists = code_lists(args.rev)
    own = [x for x in lists if "keyed table" not in x and "generated" not in x]
    gen = [x for x in lists if "generated" in x]
    print(f"{where}: status/reason definitions: {len(own)} (+{len(gen)} generated from them, "
          f"+{len(lists) - len(own) - len(gen)} tables keyed by code)")
    for x in lists:
        print("  " + x)
    if args.rev is None or args.tree:
        total, user, calibrated = user_settings(args.tree)
        print(f"{args.tree or where}: estimator settings (PipelineConfig leaves): {total}, user settings: {user}, "
              f"calibrated constants (written by soilocp calibrate): {calibrated}, internal: {total - user - calibrated}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
