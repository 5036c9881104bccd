"""The `jaxdefl` command line: thin wrappers that parse flags and call `pipeline`."""

from __future__ import annotations

import signal
import sys
import warnings
from contextlib import contextmanager
from pathlib import Path
from typing import Annotated

import typer

from . import settings as _settings  # the defaults of every flag (one source)
from ._errors import Interrupted, JaxdeflError, ParameterError, one_line
from ._signals import check_interrupt, committed_under_signal, handle_signals, note_finished

app = typer.Typer(
    add_completion=False,
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    help="Dynamic deflection of structures from range cameras.",
)

_state = {"debug": False}


@app.callback()
def _root(
    debug: Annotated[bool, typer.Option("--debug", help="Show tracebacks on errors.")] = False,
) -> None:
    _state["debug"] = debug


_WAIT_HELP = "When another jaxdefl command writes to the same --out: wait for it (default: exit 2)."

_TIMESTAMPS_HELP = (
    "strict (default: a repeated time with other values is an error), reclock (recover the "
    "sample clock of rounded or jittered stamps) or merge (average true duplicates)."
)


@app.command()
def fit(
    traj: Annotated[
        Path,
        typer.Argument(help="Trajectory table, CSV or Parquet (t, plate, z or a wide logger table)."),
    ],
    out: Annotated[
        Path,
        typer.Option(
            "--out",
            help="Estimates table to write, CSV or Parquet by its suffix (.csv, .parquet, .pq); "
            "OUT.json (the settings) and, with --reference or --posterior, OUT_reference, "
            "OUT_comparison, OUT_uncertainty, OUT_posterior in the same format beside it.",
        ),
    ],
    window: Annotated[float | None, typer.Option(help="Window length in s (default: whole segment).")] = None,
    step: Annotated[float | None, typer.Option(help="Window step in s (default: the window length).")] = None,
    axes: Annotated[
        str | None, typer.Option(help="Axes to fit, comma separated (default: z, x, y as present).")
    ] = None,
    fmin: Annotated[float | None, typer.Option(help="Lowest frequency searched, Hz.")] = None,
    fmax: Annotated[
        float | None, typer.Option(help="Highest frequency searched, Hz (default: Nyquist).")
    ] = None,
    oversampling: Annotated[
        float, typer.Option(help="Periodogram oversampling factor.")
    ] = _settings.FitSettings.oversampling,
    fap_max: Annotated[
        float, typer.Option(help="Largest peak false-alarm probability that is fitted.")
    ] = _settings.FitSettings.fap_max,
    reference: Annotated[Path | None, typer.Option(help="Reference (LDS) table t, plate, z.")] = None,
    posterior: Annotated[
        int | None,
        typer.Option(help="Check N windows' σ's against emcee posteriors (0: honesty flags only)."),
    ] = None,
    timestamps: Annotated[
        str, typer.Option("--timestamps", help=_TIMESTAMPS_HELP)
    ] = _settings.FitSettings.timestamps,
    posterior_noise: Annotated[
        str, typer.Option(help="Noise likelihood of the posteriors: ar1 (coloured, default) or white.")
    ] = _settings.FitSettings.posterior_noise,
    model: Annotated[
        str, typer.Option(help="Signal model: harmonic (thesis) or damped (free vibration).")
    ] = _settings.FitSettings.model,
    harmonics: Annotated[
        int, typer.Option(help="Fit f0 and its harmonics 2 f0 .. K f0.")
    ] = _settings.FitSettings.harmonics,
    lines: Annotated[
        int, typer.Option(help="Fit N independent spectral lines (modes).")
    ] = _settings.FitSettings.lines,
    wait: Annotated[bool, typer.Option("--wait", help=_WAIT_HELP)] = False,
) -> None:
    """Estimate loading frequency and deflection amplitude per segment, window, plate and axis."""
    from .settings import FIT_FLAGS, FitSettings

    flags = _flag_values(locals(), FIT_FLAGS)
    with _flag_names(FIT_FLAGS):
        settings = FitSettings(**flags)  # every setting is checked before any input is read
        _jax_setup()
        from . import pipeline

        with _locked(out, "fit", wait):
            pipeline.fit_file(traj, out, settings, reference=reference)


@app.command()
def simulate(
    config: Annotated[Path, typer.Argument(help="Simulation config (TOML), e.g. configs/exp1.toml.")],
    out: Annotated[Path, typer.Option("--out", help="Output directory.")],
    duration: Annotated[float | None, typer.Option(help="Override the recording duration, s.")] = None,
    seed: Annotated[int | None, typer.Option(help="Random seed (default: from the config).")] = None,
    session: Annotated[
        str | None,
        typer.Option(help="A \\[\\[session]] of the config (default: each session in DIR/<session>/)."),
    ] = None,
    live: Annotated[
        bool,
        typer.Option(
            "--live",
            help="A live camera: append measured plate centroids to DIR/trajectory.csv as they come.",
        ),
    ] = _settings.SimulateSettings.live,
    speed: Annotated[
        float, typer.Option(help="With --live: times real time.")
    ] = _settings.SimulateSettings.speed,
    wait: Annotated[bool, typer.Option("--wait", help=_WAIT_HELP)] = False,
) -> None:
    """Simulate a recording: DIR/recording.zarr, DIR/truth.csv, DIR/lds.csv (or --live)."""
    from .settings import SIMULATE_FLAGS, SimulateSettings

    with _flag_names(SIMULATE_FLAGS):
        s = SimulateSettings(**_flag_values(locals(), SIMULATE_FLAGS))  # before any input is read
        from . import pipeline

        with _locked(out, "simulate", wait):
            pipeline.simulate_file(config, out, s)


@app.command()
def register(
    recordings: Annotated[
        list[Path], typer.Argument(help="One recording (.zarr) per camera, e.g. OUT/cam3.zarr OUT/cam4.zarr.")
    ],
    trajectory: Annotated[
        list[Path],
        typer.Option(
            "--trajectory",
            help="The camera-frame trajectory `extract` made of each recording, in the same order.",
        ),
    ],
    config: Annotated[
        Path,
        typer.Option(
            "--config", help="Config whose \\[beam], \\[plates], \\[scene] give the beam's geometry."
        ),
    ],
    out: Annotated[Path, typer.Option("--out", help="Output directory.")],
    lds: Annotated[
        Path | None,
        typer.Option(help="Reference table (t, plate, z) on the true clock: absolute clock offsets."),
    ] = None,
    sample_frames: Annotated[
        int, typer.Option(help="Frames per recording whose median gives the floor, beam top and targets.")
    ] = 100,
    wait: Annotated[bool, typer.Option("--wait", help=_WAIT_HELP)] = False,
) -> None:
    """Register several cameras into the beam's frame and onto one clock; fuse the shared plates."""
    _jax_setup()
    from . import pipeline

    with _locked(out, "register", wait):
        pipeline.register_files(recordings, trajectory, config, out, lds=lds, sample_frames=sample_frames)


@app.command()
def extract(
    recording: Annotated[
        Path,
        typer.Argument(help="Recording: a .zarr store, a TUM-style depth-PNG folder or an .npz."),
    ],
    out: Annotated[Path, typer.Option("--out", help="Trajectory table to write (CSV or Parquet).")],
    realtime: Annotated[
        bool,
        typer.Option("--realtime/--full", help="Track plates detected once (fast) or detect in every frame."),
    ] = _settings.ExtractSettings.realtime,
    chunk_frames: Annotated[
        int, typer.Option(help="Frames per batch (bounds memory).")
    ] = _settings.ExtractSettings.chunk_frames,
    device: Annotated[
        str | None,
        typer.Option(help="Torch device of the per-frame stages: cpu, cuda, cuda:N (default: cuda if any)."),
    ] = None,
    timestamps: Annotated[
        str,
        typer.Option(
            "--timestamps",
            help="strict (frame times must increase) or reclock (recover the frame clock of rounded "
            "or jittered frame times).",
        ),
    ] = _settings.ExtractSettings.timestamps,
    wait: Annotated[bool, typer.Option("--wait", help=_WAIT_HELP)] = False,
) -> None:
    """Extract the plates from every frame: 3D centroid trajectories (t, plate, x, y, z)."""
    from .settings import EXTRACT_FLAGS, ExtractSettings

    with _flag_names(EXTRACT_FLAGS):
        settings = ExtractSettings(**_flag_values(locals(), EXTRACT_FLAGS))  # before any input is read
        from . import pipeline

        with _locked(out, "extract", wait):
            pipeline.extract_file(recording, out, settings)


@app.command()
def run(
    config: Annotated[Path, typer.Argument(help="Campaign config (TOML).")],
    out: Annotated[
        Path, typer.Option("--out", help="Output directory (reused: finished units are kept).")
    ] = Path("campaign_out"),
    scheduler: Annotated[
        str,
        typer.Option(help="none (in-process), local (a dask LocalCluster) or a scheduler address."),
    ] = _settings.RunSettings.scheduler,
    timestamps: Annotated[
        str | None,
        typer.Option("--timestamps", help="Override processing.timestamps: " + _TIMESTAMPS_HELP),
    ] = None,
    wait: Annotated[bool, typer.Option("--wait", help=_WAIT_HELP)] = False,
) -> None:
    """Reprocess a campaign (days x cameras) to tables, a Zarr dataset, figures and a report."""
    from .settings import RUN_FLAGS, RunSettings

    with _flag_names(RUN_FLAGS):
        settings = RunSettings(**_flag_values(locals(), RUN_FLAGS))  # before any input is read
        _jax_setup()
        from . import pipeline

        with _locked(out, "run", wait):
            pipeline.run_file(config, out, settings)


@app.command()
def diagnose(
    traj: Annotated[Path, typer.Argument(help="Trajectory table (CSV or Parquet).")],
    out: Annotated[
        Path, typer.Option("--out", help="Diagnosis to write (JSON; OUT.md and figures beside it).")
    ],
    reference: Annotated[Path | None, typer.Option(help="Reference (LDS) table t, plate, z.")] = None,
    sensor: Annotated[
        str | None, typer.Option(help="tof, structured_light, lds, accelerometer, camera_tracking or logger.")
    ] = None,
    frame_rate: Annotated[float | None, typer.Option("--frame-rate", help="Camera frame rate, Hz.")] = None,
    modulation_mhz: Annotated[
        float | None, typer.Option("--modulation-mhz", help="ToF modulation frequency, MHz.")
    ] = None,
    config: Annotated[
        Path | None, typer.Option(help="The simulation config (TOML) the recording is compared with.")
    ] = None,
    segment: Annotated[
        str | None, typer.Option(help="The segment to diagnose (tables with several).")
    ] = None,
    effects: Annotated[
        str | None, typer.Option(help="Restrict the library to these effect ids, comma separated.")
    ] = None,
    alpha: Annotated[
        float,
        typer.Option(
            "--alpha",
            help="Family-wise false-alarm level of the named effects: a record of the nominal model "
            "gets any effect named with at most this probability.",
        ),
    ] = _settings.DiagnoseSettings.alpha,
    figures: Annotated[
        bool, typer.Option("--figures/--no-figures", help="Write a figure per effect.")
    ] = True,
    timestamps: Annotated[
        str, typer.Option("--timestamps", help=_TIMESTAMPS_HELP)
    ] = _settings.DiagnoseSettings.timestamps,
    wait: Annotated[bool, typer.Option("--wait", help=_WAIT_HELP)] = False,
    twins: Annotated[int, typer.Option("--twins", help=_TWINS_HELP)] = 4,
) -> None:
    """Locate where a recording departs from the nominal model and name the missing physics."""
    from .settings import DIAGNOSE_FLAGS, DiagnoseSettings

    with _flag_names(DIAGNOSE_FLAGS):
        settings = DiagnoseSettings(**_flag_values(locals(), DIAGNOSE_FLAGS))  # before any input is read
        _jax_setup()
        from . import pipeline

        with _locked(out, "diagnose", wait):
            pipeline.diagnose_file(
                traj, out, settings, reference=reference, config=config, figures=figures, twins=twins
            )


@app.command()
def attribute(
    traj: Annotated[
        Path,
        typer.Argument(
            help="Registered trajectory with a camera column (`jaxdefl register` OUT/trajectory.csv)."
        ),
    ],
    out: Annotated[Path, typer.Option("--out", help="Attribution to write (JSON; OUT.md beside it).")],
    reference: Annotated[
        Path | None, typer.Option(help="Reference (LDS) table t, plate, z on the registered clock.")
    ] = None,
    effects: Annotated[
        str | None, typer.Option(help="Restrict the library to these effect ids, comma separated.")
    ] = None,
    camera_column: Annotated[
        str, typer.Option("--camera-column", help="The column naming each row's camera.")
    ] = "camera",
    timestamps: Annotated[
        str, typer.Option("--timestamps", help=_TIMESTAMPS_HELP)
    ] = _settings.DiagnoseSettings.timestamps,
    config: Annotated[
        Path | None,
        typer.Option(
            help="The several-camera simulation config (TOML, \\[\\[camera]] tables) of the recording: "
            "each camera's sensor facts, and its twins' null."
        ),
    ] = None,
    session: Annotated[str | None, typer.Option(help="Session of the config (\\[\\[session]] name).")] = None,
    twins: Annotated[int, typer.Option("--twins", help=_TWINS_HELP)] = 4,
    wait: Annotated[bool, typer.Option("--wait", help=_WAIT_HELP)] = False,
) -> None:
    """Diagnose each camera of a multi-camera recording; say of each finding: camera side or structure."""
    from .settings import DiagnoseSettings

    if twins < 0:
        raise typer.BadParameter(f"expected a count >= 0, got {twins}", param_hint="--twins")
    settings = DiagnoseSettings(effects=effects, timestamps=timestamps)
    _jax_setup()
    from . import pipeline

    with _locked(out, "attribute", wait):
        pipeline.attribute_file(
            traj,
            out,
            settings,
            reference=reference,
            column=camera_column,
            config=config,
            session=session,
            twins=twins,
        )


_TWINS_HELP = (
    "With a config: simulated twins of it (rendered, extracted, diagnosed alike) whose findings "
    "are the sensor's own physics, not missing physics; 0: none."
)


@app.command()
def reconcile(
    recording: Annotated[
        Path, typer.Argument(help="Recording: a trajectory table (CSV/Parquet) or frames (.zarr, TUM, .npz).")
    ],
    config: Annotated[Path, typer.Option("--config", help="Simulation config of the experiment (TOML).")],
    out: Annotated[Path, typer.Option("--out", help="Output directory.")],
    reference: Annotated[Path | None, typer.Option(help="Reference (LDS) table t, plate, z.")] = None,
    session: Annotated[str | None, typer.Option(help="Session of the config (\\[\\[session]] name).")] = None,
    segment: Annotated[
        str | None, typer.Option(help="Segment of the recording (default: the first).")
    ] = None,
    null_sims: Annotated[
        int, typer.Option(help="Simulations for the null band.")
    ] = _settings.ReconcileSettings.n_null,
    seed: Annotated[
        int, typer.Option(help="Random seed of the simulations.")
    ] = _settings.ReconcileSettings.seed,
    timestamps: Annotated[
        str, typer.Option("--timestamps", help=_TIMESTAMPS_HELP)
    ] = _settings.ReconcileSettings.timestamps,
    wait: Annotated[bool, typer.Option("--wait", help=_WAIT_HELP)] = False,
    twins: Annotated[int, typer.Option("--twins", help=_TWINS_HELP)] = 4,
) -> None:
    """Compare a recording with its simulation, name the missing physics, simulate it, compare again."""
    from .settings import RECONCILE_FLAGS, ReconcileSettings

    with _flag_names(RECONCILE_FLAGS):
        settings = ReconcileSettings(**_flag_values(locals(), RECONCILE_FLAGS))  # before any input is read
        _jax_setup()
        from . import pipeline

        with _locked(out, "reconcile", wait):
            pipeline.reconcile_file(recording, config, out, settings, reference=reference, twins=twins)


@app.command()
def monitor(
    source: Annotated[
        Path | None,
        typer.Argument(help="A trajectory table (CSV) or a .zarr recording, followed as it grows."),
    ] = None,
    out: Annotated[Path, typer.Option("--out", help="Output directory.")] = Path("monitor_out"),
    replay: Annotated[
        bool, typer.Option("--replay", help="Replay SOURCE (a table or any recording) as if live.")
    ] = _settings.MonitorSettings.replay,
    config: Annotated[
        Path | None, typer.Option(help="A simulation config: monitor its live simulated camera.")
    ] = None,
    speed: Annotated[
        float, typer.Option(help="Replay or simulation speed, times real time (0: as fast as possible).")
    ] = _settings.MonitorSettings.speed,
    until: Annotated[float | None, typer.Option(help="Stop after this many s of data.")] = None,
    duration: Annotated[float | None, typer.Option(help="Stop after this many s of wall-clock time.")] = None,
    method: Annotated[
        str, typer.Option(help="Recursive estimator: ekf or rls.")
    ] = _settings.MonitorSettings.method,
    alarms_per_day: Annotated[
        float, typer.Option("--alarms-per-day", help="False alarms allowed per day of data.")
    ] = _settings.MonitorSettings.alarms_per_day,
    block: Annotated[
        float, typer.Option(help="Change-detection block length, s.")
    ] = _settings.MonitorSettings.block_s,
    snapshot: Annotated[
        float, typer.Option(help="Seconds of data between estimate snapshots.")
    ] = _settings.MonitorSettings.snapshot_s,
    idle: Annotated[
        float, typer.Option(help="A followed source ends after this many s without data.")
    ] = _settings.MonitorSettings.idle_s,
    seed: Annotated[int | None, typer.Option(help="With --config: the simulation seed.")] = None,
    reference: Annotated[
        Path | None, typer.Option(help="Reference (LDS) table t, plate, z, monitored alongside.")
    ] = None,
    timestamps: Annotated[
        str, typer.Option("--timestamps", help=_TIMESTAMPS_HELP + " (a replayed table only)")
    ] = _settings.MonitorSettings.timestamps,
    wait: Annotated[bool, typer.Option("--wait", help=_WAIT_HELP)] = False,
) -> None:
    """Follow a live camera: f0 and A per plate with σ's, alarms when the structure or a sensor changes."""
    from .settings import MONITOR_FLAGS, MonitorSettings

    with _flag_names(MONITOR_FLAGS):
        s = MonitorSettings(**_flag_values(locals(), MONITOR_FLAGS))  # before any input is read
        _jax_setup()
        from .monitor.run import run_monitor
        from .monitor.sources import open_source, simulated_source

        if config is not None and source is None:
            src = simulated_source(config, duration_s=s.until_s, seed=s.seed)
        else:
            src = open_source(
                source if not s.replay else None,
                source if s.replay else None,
                config,
                idle_s=s.idle_s,
                timestamps=s.timestamps,
            )
        inputs = tuple(p for p in (source, config, reference) if p is not None)
        with _locked(out, "monitor", wait):
            run_monitor(src, out, s, inputs=inputs, reference=reference)


@app.command()
def demo(
    out: Annotated[Path, typer.Option("--out", help="Report directory.")] = Path("demo_out"),
    duration: Annotated[float, typer.Option(help="Simulated duration, s.")] = 120.0,
    seed: Annotated[int, typer.Option(help="Random seed.")] = 1,
    wait: Annotated[bool, typer.Option("--wait", help=_WAIT_HELP)] = False,
) -> None:
    """Run the main job on the built-in default (Experiment II, 3 Hz, SR4000 at 20 Hz) to a report."""
    _jax_setup()
    from . import pipeline

    with _locked(out, "demo", wait):
        pipeline.demo(out, duration_s=duration, seed=seed)


def _jax_setup() -> None:
    """Float64 and the compilation cache for the whole process (`jaxdefl._jax.setup`), by the
    commands whose stages run JAX, once their settings are checked: --help, a bad flag, `extract`
    and `simulate` (its ToF renderer has a scope of its own) never load JAX."""
    from ._jax import setup

    setup()


def _locked(out: Path, command: str, wait: bool):
    """One command per output (`jaxdefl.io.lock`): a second one on OUT exits 2 or, with
    --wait, waits; a killed holder's lock and temporary files are cleared."""
    from .io.lock import output_lock

    return output_lock(out, command=f"jaxdefl {command}", wait=wait)


def _flag_values(given: dict, flags: dict[str, str]) -> dict:
    """A command's settings by parameter name from its arguments (named after the flags)."""
    return {param: given[flag.lstrip("-").replace("-", "_")] for param, flag in flags.items()}


@contextmanager
def _flag_names(flags: dict[str, str]):
    """A `ParameterError` of a command's settings or stages names the command's flags."""
    try:
        yield
    except ParameterError as err:
        raise err.renamed(flags) from None


# what to change when a command runs out of memory, in the flags it has
_OOM_ADVICE = {
    "fit": "use shorter windows (--window), a longer --step, a smaller --oversampling or fewer plates",
    "simulate": "use a shorter --duration or a smaller recording.chunk_frames in the config",
    "extract": "use a smaller --chunk-frames",
    "run": "use a shorter processing.window_s, a longer processing.step_s or fewer recordings",
    "diagnose": "diagnose a shorter record or one --segment",
    "reconcile": "use fewer --null-sims or a shorter record",
    "monitor": "use a shorter --block or --snapshot",
    "demo": "use a shorter --duration",
    "": "use a smaller input",
}


def _command(argv: list[str]) -> str:
    return next((a for a in argv if not a.startswith("-")), "")


def _interrupted_message(err: Interrupted, argv: list[str]) -> str:
    cmd = _command(argv)
    if cmd == "run":
        return f"interrupted ({err}): finished units are kept; run the same command again to resume"
    if cmd == "monitor":
        return f"interrupted ({err}): the monitor stopped; events.jsonl and estimates.csv hold all up to now"
    if committed_under_signal():
        return f"interrupted ({err}) while the outputs were committed: they are whole and new"
    return f"interrupted ({err}): no output was written; earlier outputs are as they were"


def main(argv: list[str] | None = None) -> int:
    """Console entry point: one-line errors; exit 2 for bad config/arguments, 1 for failures,
    130/143 when interrupted by SIGINT/SIGTERM (temporary files removed, outputs untouched)."""
    argv = list(sys.argv[1:] if argv is None else argv)
    _state["debug"] = "--debug" in argv
    try:
        with handle_signals(), warnings.catch_warnings():
            if not _state["debug"]:
                # numeric warnings (NaN windows, empty slices) are reported as statuses instead
                warnings.simplefilter("ignore", RuntimeWarning)
            code = _run(argv)
            if code == 0:
                note_finished()
            check_interrupt()  # a signal whose exception was lost (see jaxdefl._signals)
            return code
    except Interrupted as err:
        print(f"jaxdefl: {_interrupted_message(err, argv)}", file=sys.stderr)
        return err.exit_code


def _usage_message(err: typer.TyperException) -> str:
    """A click/typer usage error as one line that names the flag (or argument) and what it expected."""
    hint = None
    param = getattr(err, "param", None)
    if getattr(err, "param_hint", None) is not None:
        hint = err.param_hint if isinstance(err.param_hint, str) else " / ".join(err.param_hint)
    elif param is not None:
        names = [o for o in getattr(param, "opts", []) if o.startswith("--")]
        hint = names[0] if names else str(getattr(param, "human_readable_name", param.name))
    cause = err.__cause__
    if hint is not None and cause is not None and hasattr(cause, "errors"):  # a pydantic coercion
        first = cause.errors()[0]
        expected = _EXPECTED.get(first.get("type"), first.get("msg", str(err.message)))
        return f"{hint}: expected {expected}, got {first.get('input')!r}"
    if type(err).__name__ == "MissingParameter":
        return err.format_message().rstrip(".")
    if hint is not None:
        return f"{hint}: {err.message}"
    ctx = getattr(err, "ctx", None)
    where = f"; see `{ctx.command_path} --help`" if ctx is not None else ""
    return f"{err.format_message().rstrip('.')}{where}"


# pydantic's error types of typer's conversions, as what the flag expected
_EXPECTED = {
    "float_parsing": "a number",
    "float_type": "a number",
    "int_parsing": "an integer",
    "int_from_float": "an integer",
    "int_type": "an integer",
    "bool_parsing": "true or false",
}


def _run(argv: list[str]) -> int:
    try:
        rv = app(args=argv, prog_name="jaxdefl", standalone_mode=False)
    except JaxdeflError as err:
        if _state["debug"]:
            raise
        print(f"jaxdefl: error: {one_line(err)}", file=sys.stderr)
        return err.exit_code
    except KeyboardInterrupt:  # a SIGINT that arrived before the handler was installed
        raise Interrupted(signal.SIGINT) from None
    except typer.Exit as ex:
        return ex.exit_code
    except typer.TyperException as err:  # every click/typer usage error: one line, exit 2
        if type(err).__name__ == "NoArgsIsHelpError":  # `jaxdefl` alone: the help
            err.show()
            return 0
        print(f"jaxdefl: error: {one_line(_usage_message(err))}", file=sys.stderr)
        return 2
    except typer.Abort:  # pragma: no cover - a prompt aborted; jaxdefl has none
        print("jaxdefl: error: aborted", file=sys.stderr)
        return 2
    except OSError as err:
        if _state["debug"]:
            raise
        where = f"{err.filename}: " if err.filename else ""
        print(f"jaxdefl: error: {one_line(f'{where}{err.strerror or err}')}", file=sys.stderr)
        return 1
    except MemoryError:
        if _state["debug"]:
            raise
        print(
            f"jaxdefl: error: out of memory ({_OOM_ADVICE.get(_command(argv), _OOM_ADVICE[''])})",
            file=sys.stderr,
        )
        return 1
    except Exception as err:
        if _state["debug"]:
            raise
        print(f"jaxdefl: error: {one_line(f'{type(err).__name__}: {err}')}", file=sys.stderr)
        return 1
    # typer hands back an Exit's code (its own KeyboardInterrupt handling returns 130)
    if isinstance(rv, int) and not isinstance(rv, bool) and rv != 0:
        return rv
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
