"""An estimator is its module and its test: a toy written to a temporary module and registered
runs through replay (the API and the command), evaluate (in worker processes), tune's search
space, the view and ``mavattitude estimators``, with nothing elsewhere naming it. What the tool
needs to know about it (colour, compile cost, the log's defaults, the events it marks, heading
or not) it reads from the class."""
from __future__ import annotations

import importlib
import json
import sys
import textwrap

import pytest

import mavattitude
from conftest import SAMPLE_LOGS
from mavattitude.cli import main
from mavattitude.estimators import ESTIMATORS, plugin_paths

TOY_MODULE = "toy_estimator"
TOY_SOURCE = textwrap.dedent('''
    """Toy: the gyro integrated, pulled towards the accelerometer's tilt by a fixed gain (a test's own)."""
    from dataclasses import dataclass

    import numpy as np
    from numba import njit

    from mavattitude import quaternion as quat
    from mavattitude.estimators import Estimator, register
    from mavattitude.estimators.base import MAX_STEP_S, Marked
    from mavattitude.paramspec import param


    @dataclass
    class ToyParams:
        gain: float = param(0.1, "(0, 10]", "log [0.01, 1]")  # rad/s per unit of tilt error


    @register
    class Toy(Estimator):
        name = "toy"
        Params = ToyParams
        DIAGNOSTICS = {"tilt_error": "|down measured x down estimated|, the correction's size",
                       "start": "1 at the first sample after initialize, else 0"}
        MARKS = {"start": Marked("started from the alignment", "started", "starts")}

        @classmethod
        def log_defaults(cls, params, vehicle):
            value = params.get("TOY_GAIN")
            return {} if value is None else {"gain": (float(value), "from TOY_GAIN (the log's own)")}

        def initialize(self, q0, gyro_bias, accel_g=9.80665):
            self.q = np.array(q0, dtype=float) / np.linalg.norm(q0)
            self.bias = np.array(gyro_bias, dtype=float).reshape(3)
            self.t_prev, self.starting, self.initialized = None, True, True

        def update(self, t, gyro, accel, mag, in_air=None, aiding=None):
            s = self._chunk(t, gyro, accel, mag, in_air)
            n = len(s.t)
            out, error, start = np.empty((n, 4)), np.zeros(n), np.zeros(n)
            start[:1] = float(self.starting)
            self.starting = False
            for i in range(n):
                w = s.gyro[i] - self.bias
                norm = np.linalg.norm(s.accel[i])
                if np.isfinite(norm) and norm > 0:
                    measured = -s.accel[i] / norm  # "down" in the body: specific force is -g
                    estimated = quat.rotate(quat.conjugate(self.q), np.array([0.0, 0.0, 1.0]))
                    e = np.cross(measured, estimated)
                    w = w + self.params.gain * e
                    error[i] = np.linalg.norm(e)
                if self.t_prev is not None and 0.0 < s.t[i] - self.t_prev <= MAX_STEP_S:
                    self.q = quat.integrate_gyro(self.q, w, s.t[i] - self.t_prev)
                self.t_prev, out[i] = s.t[i], self.q
            self.diagnostics = {"tilt_error": error, "start": start}
            return out


    @njit(cache=True)
    def toy_kernel(x):
        return x + 1.0


    @register
    class ToyJit(Toy):
        """The toy with a numba kernel and no compile cost stated."""
        name = "toy-jit"
        kernels = (toy_kernel,)

        def update(self, t, gyro, accel, mag, in_air=None, aiding=None):
            toy_kernel(0.0)
            return super().update(t, gyro, accel, mag, in_air, aiding)
''')
NAMES = ("toy", "toy-jit")


@pytest.fixture(scope="module")
def toy(tmp_path_factory):
    """The toy's module in a folder of its own on sys.path, imported (it registers itself);
    afterwards unregistered and forgotten, so no other test sees it."""
    folder = tmp_path_factory.mktemp("toy")
    (folder / f"{TOY_MODULE}.py").write_text(TOY_SOURCE)
    sys.path.insert(0, str(folder))
    try:
        module = importlib.import_module(TOY_MODULE)
        yield module
    finally:
        for name in NAMES:
            ESTIMATORS.pop(name, None)
        sys.modules.pop(TOY_MODULE, None)
        sys.path.remove(str(folder))


def test_the_toy_is_listed_with_its_parameters(toy, capsys):
    assert main(["estimators"]) == 0
    out = capsys.readouterr().out
    assert "toy: Toy: the gyro integrated, pulled towards the accelerometer's tilt" in out
    assert "--set toy.gain" in out and "[tune: log [0.01, 1]]" in out and "diagnostic start: 1 at the first" in out
    assert main(["estimators", "--json"]) == 0
    listed = json.loads(capsys.readouterr().out)["toy"]
    assert listed["uses_magnetometer"] is False and set(listed["params"]) == {"gain"}


def test_what_the_tool_reads_from_the_class(toy, monkeypatch):
    """Colour: none stated, so a spare one no other estimator or role has; a stated one is
    taken. Compile cost: none stated, so the default where there are kernels. Heading: none (no
    compass). Where other processes find it: its module. Tune: its search space."""
    from mavattitude import view
    from mavattitude.core import warmup
    from mavattitude.estimators import create, needs_compile
    from mavattitude.estimators.base import DEFAULT_COMPILE_S
    from mavattitude.commands.tune import TuneSettings, space_for
    from mavattitude.errors import UsageError
    from mavattitude.core.policy import RunOptions

    names = [*ESTIMATORS, "autopilot", "truth", "autopilot:EKF1 (EKF1)"]
    colors = view.assign_colors(names)
    assert colors["toy"] not in [c for n, c in colors.items() if n != "toy"]
    assert colors == view.assign_colors(names)  # the same every time
    monkeypatch.setattr(toy.Toy, "color", (10, 20, 30))
    assert view.assign_colors(["toy", "mahony"]) == {"toy": (10, 20, 30), "mahony": ESTIMATORS["mahony"].color}
    assert warmup.compile_seconds("toy-jit") == DEFAULT_COMPILE_S and needs_compile(["toy"]) == []
    # handed out by cost, longest first, each to the first process free: cpf-ekf 13 s; the toy 5 s (the default), mahony 1.5 s
    assert warmup.longest_first(["mahony", "toy-jit", "cpf-ekf"]) == ["cpf-ekf", "toy-jit", "mahony"]
    assert not create("toy").has_heading_reference(True)
    assert plugin_paths(["mahony", "toy", "toy-jit"]) == {"toy": f"{TOY_MODULE}:Toy", "toy-jit": f"{TOY_MODULE}:ToyJit"}
    # tune: its search space from the class, and nothing left once --set fixes the one field
    space = space_for(TuneSettings("toy", RunOptions(names=("toy",))))
    assert list(space) == ["gain"] and str(space["gain"]) == "log [0.01, 1]"
    with pytest.raises(UsageError, match="nothing to tune"):
        space_for(TuneSettings("toy", RunOptions(names=("toy",), assignments=("toy.gain=2",))))


@pytest.mark.slow  # a process that imports the package and numba: 4 s
def test_a_compiling_process_registers_the_toy_from_its_module(toy):
    """warmup's processes compile an estimator registered at run time: it is registered there
    from its module, compiled, and said done."""
    from mavattitude.core import warmup
    from mavattitude.estimators import needs_compile

    assert needs_compile(["toy-jit"]) == ["toy-jit"]  # a fresh folder: nothing cached
    process = warmup.compiling_process(["toy-jit"], list(plugin_paths(["toy-jit"]).values()))
    out, _ = process.communicate(timeout=300)
    assert process.returncode == 0 and out.decode().split()[0] == "toy-jit"
    assert needs_compile(["toy-jit"]) == []


def test_replay_from_the_api_takes_the_logs_default_and_marks_its_events(toy, tmp_path):
    flight = mavattitude.load(SAMPLE_LOGS / "figure8.bin")
    flight.params["TOY_GAIN"] = 0.05
    result = mavattitude.replay(flight, estimators=["toy", "mahony"], reference="truth")
    assert result.params["toy"].gain == 0.05
    toy_row = result.metrics["estimators"]["toy"]
    assert toy_row["roll"]["mae"] < 0.5 and toy_row["pitch"]["mae"] < 3.0  # measured 0.2°, 1.6°
    assert toy_row["yaw"]["aligned"] is True  # no heading reference: yaw scored as drift
    assert toy_row["events"]["starts"]["count"] == 1
    assert [e.text for e in result.events if e.text.startswith("toy:")] == ["toy: started from the alignment"]
    result.write_rrd(tmp_path / "toy.rrd")  # the view: the toy's own subtree beside mahony's
    assert b"est/toy/attitude" in (tmp_path / "toy.rrd").read_bytes()


def test_replay_from_the_command_with_its_recording(toy, tmp_path, capsys):
    rrd, metrics = tmp_path / "static.rrd", tmp_path / "static.json"
    code = main(["replay", str(SAMPLE_LOGS / "static.bin"), "--estimators", "toy,mahony", "--rrd", str(rrd),
                 "--json", str(metrics)])
    out, err = capsys.readouterr()
    assert code == 0, err
    assert "toy" in out and b"est/toy/attitude" in rrd.read_bytes()
    assert json.loads(metrics.read_text())["estimators"]["toy"]["params"] == {"gain": 0.1}


@pytest.mark.slow  # 13 s: two spawned workers import the package
def test_evaluate_runs_the_toy_in_worker_processes(toy, tmp_path, capsys):
    """-j 2: spawned workers register the toy from its module (on this process's sys.path);
    without that each log fails with "unknown estimator 'toy'"."""
    logs = [str(SAMPLE_LOGS / "figure8.bin"), str(SAMPLE_LOGS / "static.bin")]
    code = main(["evaluate", *logs, "--estimators", "toy,mahony", "-j", "2", "--out", str(tmp_path / "eval"), "-q"])
    _, err = capsys.readouterr()
    assert code == 0, err
    summary = json.loads((tmp_path / "eval" / "summary.json").read_text())
    assert summary["estimators"]["toy"]["logs"] == 2 and summary["failed"] == []


def test_evaluate_refuses_an_estimator_its_workers_cannot_import(toy):
    from mavattitude.errors import UsageError
    from mavattitude.estimators import register
    from mavattitude.commands.evaluate import Workers
    from mavattitude.core.policy import RunOptions

    @register
    class Local(toy.Toy):
        name = "toy-local"

    try:
        with Workers(2) as workers, pytest.raises(UsageError, match="define it in a module, or run with -j 1"):
            workers.run(["a.bin", "b.bin"], RunOptions(names=("toy-local",)), print)
    finally:
        ESTIMATORS.pop("toy-local")



@pytest.mark.slow  # a Dask cluster on loopback: 20 s
def test_evaluate_on_a_dask_cluster_registers_the_toy_on_its_worker(toy, tmp_path, capsys):
    """Each task registers the toy from its module first (the worker, spawned here, has this
    process's sys.path; a remote one needs the module installed)."""
    distributed = pytest.importorskip("distributed")
    logs = [str(SAMPLE_LOGS / "static.bin"), str(SAMPLE_LOGS / "hover.tlog")]
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=True, host="127.0.0.1",
                                  dashboard_address=":0") as cluster:
        code = main(["evaluate", *logs, "--estimators", "toy,mahony", "--scheduler", cluster.scheduler_address,
                     "--out", str(tmp_path / "dask"), "-q"])
    _, err = capsys.readouterr()
    assert code == 0, err
    summary = json.loads((tmp_path / "dask" / "summary.json").read_text())
    assert summary["estimators"]["toy"]["logs"] == 2 and summary["failed"] == []


def test_a_class_uses_the_compass_where_its_parameters_have_a_use_mag_switch():
    """``Estimator.uses_mag`` unsaid: from whether its Params has ``use_mag``; said, as said."""
    from dataclasses import dataclass

    from mavattitude.estimators.base import Estimator

    @dataclass
    class WithSwitch:
        use_mag: bool = True

    @dataclass
    class WithoutSwitch:
        gain: float = 0.1

    class Heading(Estimator):
        Params = WithSwitch

    class Tilt(Estimator):
        Params = WithoutSwitch

    class Said(Estimator):
        Params = WithSwitch
        uses_mag = False

    assert Heading.uses_mag and not Tilt.uses_mag and not Said.uses_mag
