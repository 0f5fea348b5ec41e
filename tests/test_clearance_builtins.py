"""Every built-in mechanism with a clearance at each of its revolute pairs: the ideal outputs at
zero offsets, a finite worst case, and `sewtol run FILE montecarlo` working on the file."""

import numpy as np
import pytest

from sewtol import mechanisms as M
from sewtol.mechanism.clearance import pair_joints
from sewtol.mechanism.loader import loads
from sewtol.studies import clearance as K


def with_pins(name):
    text = M.mechanism_file(name).read_text()
    bare = loads(text, f"{name}.toml")
    joints = sorted(pair_joints(bare.groups)["revolute"])
    pins = "".join(f'\n[[clearances]]\njoint = "{j}"\nradial_mm = 0.005\n' for j in joints)
    return text + pins, bare, loads(text + pins, f"{name}.toml"), joints


@pytest.mark.parametrize("name", M.names())
def test_every_builtin_takes_pin_clearances(name, tmp_path):
    from cli_helpers import run, strict_loads

    text, bare, mech, joints = with_pins(name)
    assert len(mech.pair_parameters) == 2 * len(joints) > 0
    a, b = mech.evaluate(), bare.evaluate()
    for k in b.outputs:
        np.testing.assert_array_equal(a.outputs[k], b.outputs[k])
    f = tmp_path / f"{name}.toml"
    f.write_text(text)
    code, out, err = run("run", str(f), "montecarlo", "--n", "4", "--seed", "1",
                         "--format", "json")
    assert code == 0, err
    assert strict_loads(out)
    # the journals as further variables beside the file's first tolerance set
    code, out, err = run("run", str(f), "montecarlo", "--n", "4", "--seed", "1",
                         "--clearances", "disc", "--format", "json")
    if name == "presser_foot":
        # its contact outputs come from a kernel of its own that does not see the journals:
        # refused in one line, never the ideal pairs' answer; its outputs of points run
        assert code == 2 and err.count("\n") == 1 and "presser_contact" in err, err
        point_output = next(o.name for o in mech.outputs if o.type != "custom")
        code, out, err = run("run", str(f), "montecarlo", "--n", "4", "--seed", "1",
                             "--clearances", "disc", "--output", point_output,
                             "--format", "json")
    assert code == 0, err
    got = strict_loads(out)
    assert got["tolerances"].endswith("+clearances")
    signals = [o.name for o in mech.outputs if o.type in K.SIGNAL_TYPES]
    if signals and a.status[0] == "ok":
        wc = K.worst_case(mech, None, signals[0])
        if name.startswith("spatial"):
            # the spatial groups take lengths, not the points O and B the file draws: a pin
            # there enters nothing, and the worst case says so
            assert wc.inert == tuple(joints) and not np.any(wc.total)
            return
        assert wc.inert == () or set(wc.inert) < set(joints)
        assert np.all(np.isfinite(wc.total)) and np.all(wc.total > 0)
        # the offsets that W prescribes move the real model by W, to first order
        k = int(np.argmax(wc.total[0]))
        values = {}
        for j, r in wc.argmax_mm.items():
            values[f"{j}_dx_mm"], values[f"{j}_dy_mm"] = [r[0, k].real], [r[0, k].imag]
        moved = K.signal(mech, mech.state(values), signals[0])[0, k]
        base = K.signal(mech, mech.state(), signals[0])[0, k]
        assert moved - base == pytest.approx(wc.total[0, k], rel=0.02)
