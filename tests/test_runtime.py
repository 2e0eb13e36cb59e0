"""panovocc_cli.runtime: importing the package changes nothing; setup() applies the process settings
once, keeps the user's own environment values, and the command line calls it."""

import os
import subprocess
import sys

PROBE = ("import os, sys\n"
         "import panovocc_cli, panovocc_cli.cli, panovocc_cli.io.images, panovocc_cli.mapping.contributors\n"
         "before = os.environ.get('OMP_WAIT_POLICY'), os.environ.get('NUMBA_THREADING_LAYER_PRIORITY')\n"
         "import panovocc_cli.runtime as rt\n"
         "first = rt.setup(); second = rt.setup()\n"
         "print(before[0], before[1] is None, first['env']['OMP_WAIT_POLICY'], os.environ['OMP_WAIT_POLICY'],\n"
         "      first is second, first['heap'])\n")


def _env(**over):
    env = {k: v for k, v in os.environ.items() if k not in ("OMP_WAIT_POLICY", "NUMBA_THREADING_LAYER_PRIORITY")}
    env.update(over)
    return env


def _run(code, env):
    return subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True).stdout


def test_import_has_no_side_effects_and_setup_applies_the_settings_once():
    out = _run(PROBE, _env()).split()
    assert out[:2] == ["None", "True"]  # importing set nothing
    assert out[2:5] == ["passive", "passive", "True"]  # setup() set it; a second call is the same answer
    if sys.platform.startswith("linux") and os.confstr("CS_GNU_LIBC_VERSION"):
        assert out[5] == "True"  # glibc heap thresholds set


def test_setup_keeps_the_users_own_values():
    out = _run(PROBE, _env(OMP_WAIT_POLICY="active")).split()
    assert out[0] == "active" and out[2:4] == ["active", "active"]


def test_the_command_line_calls_setup():
    code = ("import os, sys\n"
            "from panovocc_cli.cli import main\n"
            "try:\n    main(['version'])\n"
            "except SystemExit:\n    pass\n"
            "print(os.environ.get('OMP_WAIT_POLICY'), os.environ.get('NUMBA_THREADING_LAYER_PRIORITY'))\n")
    assert _run(code, _env()).splitlines()[-1] == "passive omp workqueue tbb"


def test_setup_after_numba_was_imported_still_sets_its_threading_order():
    code = ("import numba, panovocc_cli.mapping.contributors\n"
            "import panovocc_cli.runtime as rt\n"
            "rt.setup()\n"
            "print(' '.join(numba.config.THREADING_LAYER_PRIORITY))\n")
    assert _run(code, _env()).strip() == "omp workqueue tbb"


def test_check_memory_refuses_an_estimate_beyond_the_memory_available(monkeypatch):
    """The one memory check of the commands (gt, baselines run single-pano, baselines merge, convert
    holo360d): within MEMORY_SHARE of what is available passes, beyond it (or inf) is one line naming
    the need, what is there and what to change."""
    import pytest

    from panovocc_cli import runtime
    from panovocc_cli.errors import PanovoccError

    assert runtime.available_memory() > 0
    monkeypatch.setattr(runtime, "available_memory", lambda: 10 * 2 ** 30)
    runtime.check_memory(8 * 2 ** 30, "a grid", "choose less")  # 80 %: fits
    for need in (8.1 * 2 ** 30, float("inf"), 1e300):
        with pytest.raises(PanovoccError) as e:
            runtime.check_memory(need, "a grid", "choose less", path="x.npz")
        msg = str(e.value)
        assert msg.startswith("x.npz: a grid needs about ") and "10.0 GiB is available: choose less" in msg, msg
        assert "\n" not in msg


def _entry(prelude: str, argv: list, env=None) -> subprocess.CompletedProcess:
    """``panovocc ARGV`` through the console entry point (:func:`panovocc_cli.cli.entry`) after ``prelude``."""
    code = (prelude + "\nimport sys\nsys.argv = ['panovocc'] + " + repr(argv) + "\n"
            "from panovocc_cli.cli import entry\nentry()\nprint('not reached')\n")
    return subprocess.run([sys.executable, "-c", code], env=env or _env(), capture_output=True, text=True)


def test_the_entry_point_runs_exit_handlers_and_flushes_before_its_quick_exit():
    """After a command that succeeded the process ends in runtime.quick_exit: the atexit handlers have run,
    buffered output is out (stdout is a pipe here), the status is 0 and nothing after entry() runs."""
    r = _entry("import atexit\natexit.register(lambda: print('handler ran', flush=False))", ["version"])
    from panovocc_cli import __version__

    assert r.returncode == 0, r.stderr
    assert r.stdout.splitlines() == [__version__, "handler ran"]


def test_the_entry_point_leaves_a_failure_to_the_normal_exit():
    r = _entry("import atexit\natexit.register(lambda: print('handler ran'))", ["eval", "/nonexistent/p.npz",
                                                                              "/nonexistent/g.npz"])
    assert r.returncode == 2 and r.stderr.startswith("error: ") and "Traceback" not in r.stderr
    assert r.stdout.splitlines() == ["handler ran"]


def test_the_entry_point_waits_for_a_thread_still_working(tmp_path):
    """A thread that is not a daemon and still runs when the command returns is not cut short: the process exits
    the normal way, after it (its file is written)."""
    out = tmp_path / "late.txt"
    prelude = ("import threading, time\n"
               f"def work():\n    time.sleep(0.5)\n    open({str(out)!r}, 'w').write('done')\n"
               "threading.Thread(target=work).start()")
    r = _entry(prelude, ["version"])
    assert r.returncode == 0, r.stderr
    assert out.read_text() == "done"


def test_python_m_panovocc_cli_goes_through_the_entry_point():
    r = subprocess.run([sys.executable, "-m", "panovocc_cli", "version"], capture_output=True, text=True, env=_env())
    from panovocc_cli import __version__

    assert r.returncode == 0 and r.stdout.strip() == __version__
