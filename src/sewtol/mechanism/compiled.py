"""A mechanism file's groups compiled into one numba kernel over (machines x angles).

`compiled(mech, outputs)` generates Python source from the file's groups and the outputs asked
for, compiles it with numba's disk cache (the source named by its hash under `kernel_dir`) and
returns a `CompiledModel` whose ``evaluate(values)`` gives `FileMechanism.evaluate`'s
`Evaluation` without a (machines, angles) array: each machine is one pass over the angles, each
output reduced as it goes. Per-machine quantities are computed by numpy first, with the
reference's expressions; the kernel follows sewtol.engine operation for operation and equals it
to rounding (tests/test_compiled.py). A dead-point test takes arcsin once per machine of the
smallest sine (arcsin is monotone). What it does not cover returns None from `compiled`, with
the reason in `unsupported` (docs/mechanism_files.md, "The compiled kernel").
"""

from __future__ import annotations

import hashlib
import importlib.util
import os
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sewtol.mechanism.model import DEAD_POINT_DEG, Evaluation

DEG = np.pi / 180.0
GROUP_TYPES = ("point", "crank", "rrr", "on_body", "rpr", "rrp")
OUTPUT_TYPES = ("line_deviation", "coordinate", "angle", "transmission")
# where generated kernels (and numba's cache of them) live: $SEWTOL_KERNEL_DIR, else
# $XDG_CACHE_HOME/sewtol/kernels (~/.cache/sewtol/kernels), else a per-user temporary folder
KERNEL_DIR_ENV = "SEWTOL_KERNEL_DIR"
_LOADED: dict = {}


def unsupported(mech, outputs=None) -> str:
    """Why `mech`'s outputs cannot be compiled ("" when they can)."""
    if mech.clearances:
        return "the file has pair clearances"
    for g in mech.groups:
        if g.type not in GROUP_TYPES:
            return f"group {g.name} is of type {g.type}"
    names = mech.output_names if outputs is None else list(outputs)
    kinds = {g.name: g.type for g in mech.groups}
    for n in names:
        o = mech.output(n)
        if o.type not in OUTPUT_TYPES:
            return f"output {n} is of type {o.type}"
        if o.type == "transmission" and kinds.get(o.fields["group"]) != "rrr":
            return f"output {n} is the transmission of a group that is not an rrr dyad"
    return ""


@dataclass(frozen=True)
class CompiledModel:
    """The kernel of one file and output list: evaluate(values) -> Evaluation."""

    mech: object
    outputs: tuple[str, ...]
    source: str
    columns: tuple  # per-machine columns: callables cols -> array, in the kernel's order
    closures: tuple[str, ...]  # groups with a closure, assembly order
    dyads: tuple[str, ...]  # rrr groups (the ones with a transmission angle)
    scratches: int  # rows of the kernel's per-angle scratch
    kernel: object

    def evaluate(self, values: dict | None = None) -> Evaluation:
        mech = self.mech
        cols, m = mech.columns(values)
        with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
            C = np.empty((m, max(1, len(self.columns))))
            for k, fn in enumerate(self.columns):
                C[:, k] = np.broadcast_to(np.asarray(fn(cols), float), (m, 1))[:, 0]
        q = mech.angles_rad()
        nout = len(self.outputs)
        val = np.empty((m, max(1, nout)))
        arg = np.empty((m, max(1, nout)), np.int64)
        missed = np.empty((m, max(1, len(self.closures))), np.bool_)
        sgmin = np.empty((m, max(1, len(self.dyads))))
        W = np.empty((max(1, self.scratches), q.size))
        self.kernel(C, np.cos(q), np.sin(q), W, val, arg, missed, sgmin)
        with np.errstate(invalid="ignore"):
            tdeg = np.degrees(np.arcsin(np.minimum(sgmin, 1.0)))
        status = np.full(m, "ok", dtype=object)
        failed = np.full(m, "", dtype=object)
        for k, name in enumerate(self.closures):
            bad = missed[:, k] & (status == "ok")
            status[bad], failed[bad] = "cannot_close", name
        for k, name in enumerate(self.dyads):
            dead = (tdeg[:, k] < DEAD_POINT_DEG) & (status == "ok")
            status[dead], failed[dead] = "dead_point", name
        ok = status == "ok"
        out = {}
        for k, n in enumerate(self.outputs):
            o = mech.output(n)
            if o.type == "transmission":
                y = tdeg[:, self.dyads.index(o.fields["group"])]
            elif o.fields.get("measure") in ("argmax_deg", "argmin_deg"):
                y = np.degrees(q[arg[:, k]]) % 360.0
            else:
                y = val[:, k]
            out[n] = np.where(ok, y, np.nan)
        return Evaluation(out, status, failed)


def compiled(mech, outputs=None) -> CompiledModel | None:
    """The compiled model of `mech` for `outputs` (default all), None if `unsupported`."""
    names = tuple(mech.output_names if outputs is None else outputs)
    if unsupported(mech, names):
        return None
    source, columns, closures, dyads, scratches = _generate(mech, names)
    key = hashlib.sha256(source.encode()).hexdigest()[:20]
    kernel = _LOADED.get(key)
    if kernel is None:
        kernel = _LOADED[key] = _load(source, key)
    return CompiledModel(mech, names, source, tuple(columns), tuple(closures), tuple(dyads),
                         scratches, kernel)


def kernel_dir() -> Path:
    """The folder generated kernels are written to (see KERNEL_DIR_ENV)."""
    given = os.environ.get(KERNEL_DIR_ENV)
    if given:
        return Path(given)
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "sewtol" / "kernels"


def _load(source: str, key: str):
    name = f"sewtol_kernel_{key}"
    for folder in (kernel_dir(), Path(tempfile.gettempdir()) / f"sewtol-kernels-{os.getuid()}"):
        try:
            folder.mkdir(parents=True, exist_ok=True)
            path = folder / f"{name}.py"
            if not path.exists() or path.read_text() != source:
                tmp = folder / f".{name}.{os.getpid()}.tmp"
                tmp.write_text(source)
                os.replace(tmp, path)  # atomic: another process never reads half a file
            break
        except OSError:
            continue
    else:  # nowhere to write: compiled in memory, without numba's disk cache
        namespace: dict = {}
        exec(compile(source.replace("cache=True", "cache=False"), name, "exec"), namespace)
        return namespace["kernel"]
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module.kernel


class _Source:
    """The generated kernel, line by line, and the per-machine columns it reads."""

    def __init__(self):
        self.columns: list = []
        self.machine: list[str] = []  # once per machine
        self.angle: list[str] = []  # once per machine and angle
        self.final: list[str] = []  # once per machine, after the angles
        self.scratches = 0  # rows of per-angle values reduced after the angles

    def scratch(self) -> int:
        self.scratches += 1
        return self.scratches - 1

    def column(self, fn) -> str:
        self.columns.append(fn)
        return f"C[i, {len(self.columns) - 1}]"

    def expr(self, value, then=None) -> str:
        """A column holding an expression of the file (a number or Expression), optionally
        passed through `then` (numpy, the reference's own conversion)."""
        def fn(cols, value=value, then=then):
            v = value(cols) if callable(value) else value
            v = np.asarray(v, float)
            return then(v) if then is not None else v
        return self.column(fn)


def _generate(mech, names):
    s = _Source()
    pts: dict[str, tuple[str, str]] = {}  # point group -> (x, y) variable names
    angs: dict[str, str] = {}  # angle group -> variable name
    closures, dyads = [], []
    for k, g in enumerate(mech.groups):
        f = g.fields
        v = f"g{k}"
        if g.type == "point":
            x, y = s.expr(f["x"]), s.expr(f["y"])
            s.machine += [f"{v}x = {x}", f"{v}y = {y}"]
            pts[g.name] = (f"{v}x", f"{v}y")
        elif g.type == "crank":
            cx, cy = pts[f["center"]]
            r = s.expr(f["radius"])
            sense = s.expr(f.get("sense", 1.0))
            cph = s.expr(f.get("phase_deg", 0.0), lambda a: np.cos(a * DEG))
            sph = s.expr(f.get("phase_deg", 0.0), lambda a: np.sin(a * DEG))
            s.machine += [f"{v}r = {r}", f"{v}s = {sense}", f"{v}cp = {cph}", f"{v}sp = {sph}"]
            # center + radius e^{i(sense q + phase)}, the angle sum from cos q and sin q (the
            # same doubles as the reference's at phase 0 and sense +-1: sin is odd)
            s.angle += [f"{v}sq = {v}s * sq[j]",
                        f"{v}c = cq[j] * {v}cp - {v}sq * {v}sp",
                        f"{v}n = {v}sq * {v}cp + cq[j] * {v}sp",
                        f"{v}x = {cx} + {v}c * {v}r", f"{v}y = {cy} + {v}n * {v}r"]
            pts[g.name] = (f"{v}x", f"{v}y")
        elif g.type == "rrr":
            (ax, ay), (bx, by) = pts[f["p1"]], pts[f["p2"]]
            r1, r2, br = s.expr(f["r1"]), s.expr(f["r2"]), s.expr(f["branch"])
            wm, ws = s.scratch(), s.scratch()
            s.machine += [f"{v}r1 = {r1}", f"{v}r2 = {r2}", f"{v}b = {br}"]
            s.angle += [
                f"{v}dx = {bx} - {ax}", f"{v}dy = {by} - {ay}",
                f"{v}dist = np.sqrt({v}dx * {v}dx + {v}dy * {v}dy)",
                f"{v}m = _mx(_mx({v}dist - ({v}r1 + {v}r2), abs({v}r1 - {v}r2) - {v}dist), 0.0)",
                # coincident centres (closer than 1e-12 mm): no joint is defined
                f"{v}far = {v}dist > 1e-12",
                f"{v}m = {v}m if {v}far else np.inf",
                f"{v}dist = {v}dist if {v}far else np.nan",
                f"W[{wm}, j] = {v}m",
                f"{v}a = ({v}r1 * {v}r1 - {v}r2 * {v}r2 + {v}dist * {v}dist) / (2.0 * {v}dist)",
                f"{v}h2 = {v}r1 * {v}r1 - {v}a * {v}a",
                f"{v}h = np.nan if {v}m > 0.0 else np.sqrt(_mx({v}h2, 0.0))",
                # d / dist is numpy's complex division by (dist + 0i): times 1 / dist
                f"{v}inv = 1.0 / {v}dist",
                f"{v}ux = {v}dx * {v}inv", f"{v}uy = {v}dy * {v}inv",
                f"{v}bh = {v}b * {v}h",
                f"{v}x = {ax} + ({v}ux * {v}a - {v}uy * {v}bh)",
                f"{v}y = {ay} + ({v}ux * {v}bh + {v}uy * {v}a)",
                # sin of the transmission angle is |cross(J - P1, J - P2)| / (r1 r2): the
                # division (monotone for r1 r2 > 0) after the smallest cross product
                f"W[{ws}, j] = abs(({v}x - {ax}) * ({v}y - {by}) - ({v}y - {ay}) * "
                f"({v}x - {bx}))",
            ]
            s.final += [f"missed[i, {len(closures)}] = _missed(W[{wm}])",
                        f"sgmin[i, {len(dyads)}] = _nanmin(W[{ws}]) / ({v}r1 * {v}r2)"]
            closures.append(g.name)
            dyads.append(g.name)
            pts[g.name] = (f"{v}x", f"{v}y")
        elif g.type == "on_body":
            ox, oy = pts[f["origin"]]
            u, w = s.expr(f["u"]), s.expr(f.get("v", 0.0))
            co = s.expr(f.get("offset_deg", 0.0), lambda a: np.cos(a * DEG))
            so = s.expr(f.get("offset_deg", 0.0), lambda a: np.sin(a * DEG))
            s.machine += [f"{v}co = {co}", f"{v}so = {so}", f"{v}u = {u}", f"{v}w = {w}"]
            if f.get("direction") is not None:
                # e^{i ang(P->Q)} is (Q - P) / |Q - P| (1 at Q = P, as np.angle(0) = 0)
                (px, py), (qx, qy) = pts[f["direction"][0]], pts[f["direction"][1]]
                s.angle += [f"{v}vx = {qx} - {px}", f"{v}vy = {qy} - {py}",
                            f"{v}vr = np.sqrt({v}vx * {v}vx + {v}vy * {v}vy)",
                            f"{v}ec = {v}vx / {v}vr if {v}vr != 0.0 else 1.0",
                            f"{v}es = {v}vy / {v}vr if {v}vr != 0.0 else 0.0"]
            else:
                s.angle += [f"{v}ec = np.cos({angs[f['angle']]})",
                            f"{v}es = np.sin({angs[f['angle']]})"]
            # e^{i(base + offset)} by the angle sum, times the local point u + i v
            s.angle += [f"{v}c = {v}ec * {v}co - {v}es * {v}so",
                        f"{v}n = {v}es * {v}co + {v}ec * {v}so",
                        f"{v}x = {ox} + ({v}c * {v}u - {v}n * {v}w)",
                        f"{v}y = {oy} + ({v}c * {v}w + {v}n * {v}u)"]
            pts[g.name] = (f"{v}x", f"{v}y")
        elif g.type == "rpr":
            (px, py), (bx, by) = pts[f["pivot"]], pts[f["block"]]
            off = s.expr(f.get("offset", 0.0))
            wm = s.scratch()
            s.machine += [f"{v}off = {off}"]
            s.angle += [f"{v}vx = {bx} - {px}", f"{v}vy = {by} - {py}",
                        f"{v}q = np.hypot({v}vx, {v}vy)",
                        f"W[{wm}, j] = _mx(abs({v}off) - {v}q, 0.0)",
                        f"{v}a = np.arctan2({v}vy, {v}vx) - _asin({v}off / {v}q)"]
            s.final.append(f"missed[i, {len(closures)}] = _missed(W[{wm}])")
            closures.append(g.name)
            angs[g.name] = f"{v}a"
        elif g.type == "rrp":
            ax, ay = pts[f["p1"]]
            r, br = s.expr(f["r"]), s.expr(f["branch"])
            gx, gy = s.expr(f["x"]), s.expr(f["y"])
            # u = exp(i alpha): numpy's complex exp, per machine
            ux = s.expr(f["angle_deg"], lambda a: np.exp(1j * (a * DEG)).real)
            uy = s.expr(f["angle_deg"], lambda a: np.exp(1j * (a * DEG)).imag)
            wm = s.scratch()
            s.machine += [f"{v}r = {r}", f"{v}b = {br}", f"{v}gx = {gx}", f"{v}gy = {gy}",
                          f"{v}ux = {ux}", f"{v}uy = {uy}"]
            s.angle += [f"{v}wx = {ax} - {v}gx", f"{v}wy = {ay} - {v}gy",
                        f"{v}al = {v}ux * {v}wx + {v}uy * {v}wy",
                        f"{v}ac = {v}ux * {v}wy - {v}uy * {v}wx",
                        f"{v}disc = {v}r * {v}r - {v}ac * {v}ac",
                        f"{v}m = _mx(abs({v}ac) - {v}r, 0.0)",
                        f"W[{wm}, j] = {v}m",
                        f"{v}root = np.nan if {v}m > 0.0 else np.sqrt(_mx({v}disc, 0.0))",
                        f"{v}s = {v}al + {v}b * {v}root",
                        f"{v}x = {v}gx + {v}s * {v}ux", f"{v}y = {v}gy + {v}s * {v}uy"]
            s.final.append(f"missed[i, {len(closures)}] = _missed(W[{wm}])")
            closures.append(g.name)
            pts[g.name] = (f"{v}x", f"{v}y")
    for k, n in enumerate(names):
        _output(s, k, mech.output(n), pts, angs)
    body = [HELPERS, "@nb.njit(cache=True, nogil=True, error_model=\"numpy\")",
            "def kernel(C, cq, sq, W, val, arg, missed, sgmin):",
            "    for i in range(C.shape[0]):"]
    body += [" " * 8 + line for line in s.machine]
    body += [" " * 8 + "for j in range(cq.size):"]
    body += [" " * 12 + line for line in s.angle]
    body += [" " * 8 + line for line in s.final]
    return "\n".join(body) + "\n", s.columns, closures, dyads, s.scratches


# the kernel's helpers: np.maximum's NaN (b is never NaN unless a is), any nonzero miss,
# np.min's NaN, the extremes of a row with numpy's first argmax/argmin, np.unwrap + np.degrees
HELPERS = """import numpy as np
import numba as nb


@nb.njit(cache=True, inline="always")
def _mx(a, b):
    return a if not a < b else b


@nb.njit(cache=True, inline="always")
def _asin(x):
    return np.arcsin(x) if -1.0 <= x <= 1.0 else np.nan


@nb.njit(cache=True)
def _missed(w):
    for x in w:
        if not x == 0.0:
            return True
    return False


@nb.njit(cache=True)
def _nanmin(w):
    lo = np.inf
    for x in w:
        if x != x:
            return x
        if x < lo:
            lo = x
    return lo


@nb.njit(cache=True)
def _extremes(w):
    hi, lo, ihi, ilo = -np.inf, np.inf, 0, 0
    for j in range(w.size):
        x = w[j]
        if x != x:
            return np.nan, np.nan, 0, 0
        if x > hi:
            hi, ihi = x, j
        if x < lo:
            lo, ilo = x, j
    return hi, lo, ihi, ilo


@nb.njit(cache=True)
def _unwrap_degrees(w):
    cum = 0.0
    prev = w[0]
    for j in range(1, w.size):
        p = w[j]
        dd = p - prev
        mod = ((dd + np.pi) % (2.0 * np.pi)) - np.pi
        if mod == -np.pi and dd > 0.0:
            mod = np.pi
        cum += 0.0 if abs(dd) < np.pi else mod - dd
        prev = p
        w[j] = p + cum
    for j in range(w.size):
        w[j] = w[j] * (180.0 / np.pi)


"""


def _output(s: _Source, k: int, o, pts, angs):
    """An output's per-angle quantity (a scratch row), its extremes over the turn and its
    value (argmax/argmin: the index, turned into degrees by numpy)."""
    f = o.fields
    v = f"o{k}"
    measure = f.get("measure")
    if o.type == "transmission":
        s.final.append(f"val[i, {k}] = np.nan")
        return
    w = s.scratch()
    if o.type == "line_deviation":
        px, py = pts[f["point"]]
        # n = cos a - i sin a; g = x + i y + n shift 1e-3; d = 1e3 Re(conj(n) (p - g))
        cn = s.expr(f["angle_deg"], lambda a: np.cos(a * DEG))
        sn = s.expr(f["angle_deg"], lambda a: np.sin(a * DEG))
        sh = s.expr(f.get("shift_um", 0.0), lambda a: a * 1e-3)
        x, y = s.expr(f["x"]), s.expr(f["y"])
        s.machine += [f"{v}cn = {cn}", f"{v}sn = {sn}",
                      f"{v}gx = {x} + {v}cn * {sh}", f"{v}gy = {y} + (-{v}sn) * {sh}"]
        s.angle.append(f"W[{w}, j] = 1e3 * ({v}cn * ({px} - {v}gx) - {v}sn * ({py} - {v}gy))")
    elif o.type == "coordinate":
        px, py = pts[f["point"]]
        if f["axis"] == "along":  # x cos a + y sin a, a = angle_deg
            ca = s.expr(f.get("angle_deg", 0.0), lambda a: np.cos(a * DEG))
            sa = s.expr(f.get("angle_deg", 0.0), lambda a: np.sin(a * DEG))
            s.machine += [f"{v}ca = {ca}", f"{v}sa = {sa}"]
            s.angle.append(f"W[{w}, j] = {v}ca * {px} + {v}sa * {py}")
        else:
            s.angle.append(f"W[{w}, j] = {px if f['axis'] == 'x' else py}")
    elif o.type == "angle":
        if f.get("angle") is not None:
            s.angle.append(f"W[{w}, j] = {angs[f['angle']]}")
        else:
            (ax, ay), (bx, by) = pts[f["direction"][0]], pts[f["direction"][1]]
            s.angle.append(f"W[{w}, j] = np.arctan2({by} - {ay}, {bx} - {ax})")
        s.final.append(f"_unwrap_degrees(W[{w}])")
    s.final.append(f"{v}hi, {v}lo, {v}ihi, {v}ilo = _extremes(W[{w}])")
    if o.type == "line_deviation" and measure == "max_abs":
        value = f"max(abs({v}hi), abs({v}lo))"
    elif o.type == "line_deviation" and measure == "sum_extremes":
        value = f"max({v}hi, 0.0) + max(-{v}lo, 0.0)"
    elif measure == "max":
        value = f"{v}hi"
    elif measure == "min":
        value = f"{v}lo"
    else:  # range (argmax/argmin: the index)
        value = f"{v}hi - {v}lo"
    s.final += [f"val[i, {k}] = {value}",
                f"arg[i, {k}] = {v}ihi if {measure!r} == 'argmax_deg' else {v}ilo"]
