"""Run parameters (``params.yaml``), one section per stage, so that ``dvc.yaml`` can name exactly the keys a
stage uses. Each stage's owner keeps its section; add fields with defaults so old params files stay valid.
"""

from __future__ import annotations

import re
from collections.abc import Iterable
from typing import Annotated, Literal

from pydantic import Field, field_validator, model_validator

from pipeline.config import checks
from pipeline.config.base import Frozen
from pipeline.vocabulary import DOFS

#: The model names params may give, checked at load without importing the modelling stack (``auvid ingest`` loads
#: params too); tests/config/test_config_refuses.py keeps them equal to pipeline.studies.coupled's and
#: pipeline.models.decoupled's.
COUPLED_MODELS = ("rbf_svr", "two_weights_svr", "wdse_svr", "gertler_hagen", "mcfarland_whitcomb", "fossen",
                  "abkowitz", "graybox", "graybox_gh", "graybox_fossen", "graybox_abkowitz")
#: the coupled models whose inputs are nu and tau (not ``coupled.inputs``)
#: (abkowitz: nu, the thrust columns of ``coupled.inputs`` and its control-surface angles, pipeline.models.manoeuvring)
EXPLICIT_MODELS = ("gertler_hagen", "mcfarland_whitcomb", "fossen", "abkowitz")
DECOUPLED_MODELS = ("ls", "mlp", "krr", "svr", "gp")
#: what the explicit models predict, in their equations' order
PLANAR_OUTPUTS = ["udot_mps2", "vdot_mps2", "rdot_radps2"]
#: Bounds the config campaign (bench/fuzz_configs.py) found missing: a filter width beyond an hour, or more joblib
#: workers than any machine has, is a typo or a hostile file, not a setting.
MAX_WIDTH_S = 3600.0
MAX_WORKERS = 1024
#: A length of time a run can mean: up to a day (longer is a unit mistake, and overflows int64 nanoseconds on the
#: way to 1e300).
Seconds = Annotated[float, Field(gt=0, le=86_400.0)]
#: numpy's seeds are 32-bit unsigned integers.
Seed = Annotated[int, Field(ge=0, le=2**32 - 1)]
#: A filter width given per signal (s): as ``sigma_s``.
Width = Annotated[float, Field(gt=0, le=MAX_WIDTH_S)]
#: A white-noise SD in a signal's unit: from 1e-9 (a variance of 1e-18 still factorizes in the smoother; a zero one
#: does not) to 1e6 (a million rpm, m/s or rad/s is no sensor).
NoiseSd = Annotated[float, Field(ge=1e-9, le=1e6)]
#: A jerk's spectral density per DOF: within 12 orders of magnitude of what a vehicle shows (1e-6 to 1 in SI).
SpectralDensity = Annotated[float, Field(ge=1e-12, le=1e6)]
#: A frequency on the grid (Hz): from one cycle in 1000 s (a filter's settling, 3 / f, is then padding of under an
#: hour) to the Nyquist frequency of the fastest grid (``sync.rate_hz`` 1000); at load also below the run's own
#: Nyquist frequency (:class:`Params`).
Frequency = Annotated[float, Field(ge=0.001, le=500.0)]


def _unique_safe_names(names: list[str], what: str) -> list[str]:
    """Names that become paths (trials, models): safe characters (:data:`checks.SAFE_NAME`), each once."""
    for i, name in enumerate(names):
        try:
            checks.check_safe_name(name, what)
        except ValueError as err:
            raise checks.KeyedError(str(i), str(err)) from None
        if name in names[:i]:
            raise checks.KeyedError(str(i), f"{what} {name!r} is listed twice")
    return names


def _known(names: Iterable[str], known: Iterable[str], what: str) -> None:
    known = list(known)
    for i, name in enumerate(names):
        if name not in known:
            raise checks.KeyedError(str(i), f"unknown {what} {name!r}; known: {known}")


def _dof_keys(mapping: dict[str, object]) -> None:
    for key in mapping:
        if key not in DOFS:
            raise checks.KeyedError(key, f"{key!r} is not a DOF; expected one of {list(DOFS)}")


class IngestParams(Frozen):
    salvage: bool = Field(True, description="Keep every complete message of a file cut short.")
    # What one text file (CSV, .csv.gz ...) may hold; a file beyond is refused, naming the file and the limit,
    # before pandas parses it (pipeline.io.text). The defaults fit a 1-kHz log of an hour with room; the upper
    # bounds are those of the line counts (int32 positions) and of a line pandas buffers whole.
    text_max_bytes: int = Field(1 << 30, ge=1 << 10, le=(1 << 31) - 1, description=(
        "Most bytes of text in one text file, inflated for a .gz (default 1 GiB; 1 KiB to 2 GiB - 1): pandas "
        "parses a file in memory, ~100 bytes a row."))
    text_max_lines: int = Field(10_000_000, ge=1, le=(1 << 31) - 1, description=(
        "Most lines in one text file (default 10 million)."))
    text_max_line_bytes: int = Field(16 << 20, ge=1 << 10, le=1 << 30, description=(
        "Longest line of a text file, in bytes (default 16 MiB; 1 KiB to 1 GiB)."))
    checksum: Literal["sha256", "none"] = Field(
        "sha256", description="The raw log's checksum in the outputs' provenance: sha256 of its bytes, or none (no "
        "hash computed: provenance says `checksum: none` with `source_sha256: null`; saves reading the log once "
        "more). `auvid ingest --no-checksum` sets none for one call.")


class SyncParams(Frozen):
    rate_hz: float = Field(20.0, ge=0.001, le=1000.0, description="The grid's rate (Hz, 0.001 to 1000): vehicle "
                           "motion needs tens of Hz; faster sensors are interpolated onto it.")
    max_gap_s: dict[str, Annotated[float, Field(ge=0, le=86_400.0)]] = Field(
        default_factory=lambda: {"default": 0.5},
        description="Largest gap between samples bridged by interpolation, per signal ('default' for the rest).")
    interpolation: dict[str, Literal["linear", "zoh", "nearest"]] = Field(
        default_factory=dict,
        description="Per signal; default: linear for states, zoh for *_rpm commands and thrusters' PWM, nearest for "
        "*_flag.")
    min_segment_s: float = Field(5.0, ge=0, le=86_400.0, description="Shorter valid stretches get no segment id "
                                 "(s, 0 to 86400: a day).")


class DifferentiateParams(Frozen):
    method: Literal["kalman", "gaussian", "savgol"] = Field(
        "kalman", description="kalman: a Kalman/RTS smoother over every velocity and rate sensor at its own stamps "
        "with its own noise, and the vehicle's model as its process equation (pipeline.estimation); gaussian / "
        "savgol: filters of the synced grid.")
    model_passes: int = Field(
        3, ge=0, le=10, description="kalman: passes with the vehicle's model in the smoother's process equation "
        "(the logged thrust, then Coriolis and a damping fitted on the previous pass); each DOF keeps the pass of "
        "highest likelihood. 0: the kinematic (white-jerk) smoother alone, for a vehicle without a usable force "
        "model.")
    mount_yaw_sd_deg: float = Field(
        2.0, ge=0, le=30, description="kalman: how well the velocity sensor's configured mount yaw is known (SD, "
        "deg): the prior the trial's misalignment estimate is combined with; the combined estimate is undone and "
        "its SD widens u's and v's bands (pipeline.estimation.dvl_alignment). 0: the configured mount is exact.")
    actuator_offset_sd_s: float = Field(
        0.1, ge=0, le=1, description="kalman: how well the actuator streams' configured clock offset (offset_s) is "
        "known (SD, s): the prior the trial's own estimate of their timing is combined with; the combined offset "
        "is applied to the thrust where it exceeds its SD (pipeline.estimation.clock_offset). 0: the configured "
        "offset is exact.")
    rate_bias: Literal["estimate", "none"] = Field(
        "estimate", description="kalman: estimate: per rate signal (FOG, gyros), a constant bias (its own plus the "
        "Earth's rate) from the logged attitude, subtracted before the smoother and its variance added to the "
        "rate's (pipeline.estimation.rate_bias); a bias the trial cannot identify is kept. none: rates as "
        "measured.")
    noise_sd: dict[str, NoiseSd] = Field(
        default_factory=dict, description="Per signal, its white-noise SD in the signal's unit; signals not named "
        "get an SD estimated from the data (robust local fit). From 1e-9 to 1e6.")
    process_noise: dict[str, SpectralDensity] = Field(
        default_factory=dict, description="kalman: per DOF (u v w p q r), the jerk's spectral density (SI, 1e-12 to "
        "1e6); DOFs not named get it by maximum likelihood.")

    @field_validator("process_noise")
    @classmethod
    def _process_noise_per_dof(cls, process_noise: dict[str, float]) -> dict[str, float]:
        _dof_keys(process_noise)
        return process_noise
    gate_sigmas: float = Field(5.0, ge=0, le=100.0, description="kalman: measurements whose residual exceeds this "
                               "many SDs are rejected as outliers (0: none; up to 100, beyond which no Gaussian "
                               "residual is ever gated).")
    max_velocity_sd_mps: float = Field(
        0.03, gt=0, le=10.0, description="kalman: a grid sample is usable where each smoothed linear velocity's SD "
        "is within this (bridged lock losses grow it).")
    max_rate_sd_radps: float = Field(0.01, gt=0, le=10.0, description="kalman: the same for the angular rates.")
    min_segment_s: float = Field(5.0, ge=0, le=86_400.0, description="kalman: shorter usable stretches get no "
                                 "segment id (s, 0 to 86400).")
    sigma_s: float | Literal["auto"] = Field(
        "auto", description="gaussian: kernel width (s), or auto: per signal, the width of least estimated "
        "mean-square error of the derivative from the signal's noise and spectrum.")
    sigma_s_per_signal: dict[str, Width] = Field(
        default_factory=dict, description="gaussian: per velocity column (u_mps ...), a width overriding sigma_s "
        f"(s, up to {MAX_WIDTH_S:g}).")
    gaussian_degree: Literal[2, 4] = Field(
        2, description="Gaussian kernels exact for polynomials up to this degree: 2 = the plain Gaussian derivative "
        "(bias sigma^2/2 times the third derivative), 4 = bias-corrected (a Gaussian-weighted local cubic fit).")
    savgol_window_s: float | Literal["auto"] = Field(1.0, description="savgol: window (s), or auto (per signal).")
    savgol_order: int = Field(3, ge=1, le=7, description="savgol: the local polynomial's degree (higher degrees "
                              "fit the noise).")
    edge_sigmas: float = Field(3.0, ge=0, le=10.0, description="Samples within this many sigma of a segment edge "
                               "are dropped (0 to 10; a Gaussian kernel's reach is under 5 sigma).")
    notch_hz: list[Frequency] = Field(
        default_factory=list, description="Narrow-band disturbances to remove (Hz): zero-phase notches applied per "
        "segment to the velocities and accelerations on the grid, after the method (every method). The derive "
        "stage's spectral check (data/derived/<trial>.spectra.json, the report) names the frequency of a "
        "disturbance the actuators cannot have caused (a carriage or shaft vibration).")
    disturbances: Literal["remove", "keep"] = Field(
        "remove", description="remove: where the spectral check, run on each trial's accelerations against the "
        "actuator signals, finds a narrow-band disturbance no actuator explains (a carriage or shaft vibration), "
        "that DOF's velocities and acceleration are low-passed just above the actuators' band (or notched at the "
        "peaks where the band reaches them); the estimation report and the run's report name it. keep: left as "
        "they are (the derive stage's check still warns). Not applied when notch_hz or max_hz is set.")
    notch_width_hz: float = Field(0.2, ge=0.001, le=5.0, description="Each notch's -3 dB width (Hz, 0.001 to 5).")
    max_hz: float | None = Field(
        None, description="A band limit (Hz): a zero-phase 4th-order Butterworth low-pass applied with the "
        "notches; null: none. Keep it above the actuators' band that the spectral check reports.", ge=0.001, le=500.0)

    @field_validator("sigma_s", "savgol_window_s")
    @classmethod
    def _positive_width(cls, width: float | str) -> float | str:
        if width != "auto" and not 0 < width <= MAX_WIDTH_S:
            raise ValueError(f"a filter width must be 'auto' or a positive number of seconds up to {MAX_WIDTH_S:g} "
                             f"(an hour), not {width}")
        return width


class FeaturesParams(Frozen):
    tuning_fraction: float = Field(0.2, ge=0, le=0.9, description="First fraction of each trial's time: tuning block.")
    test_trials: list[str] = Field(default_factory=list, description=(
        "Trials held out of tuning and CV (final check); each must be a trial of the run (the features stage "
        "checks), named with letters, digits, '_', '.', '-'."))

    @field_validator("test_trials")
    @classmethod
    def _trial_names(cls, test_trials: list[str]) -> list[str]:
        return _unique_safe_names(test_trials, "trial")


_BODY_VELOCITY = re.compile(r"^[uvwpqr](_smooth|_meas)?_(mps|radps)$")


class CoupledParams(Frozen):
    inputs: list[str] = Field(
        default_factory=lambda: ["u_mps", "v_mps", "r_radps", "T_th1_N", "T_th2_N", "T_th3_N"],
        description="The SVRs' inputs, velocities first, then actuators: feature-store columns. The default feeds "
        "each horizontal thruster's static thrust (T_<thruster>_N, the derive stage's thrust map of its speed or "
        "PWM), not its speed: the paper's n1 n2 n3 ([u_mps, v_mps, r_radps, n1_rpm, n2_rpm, n3_rpm]) leave the "
        "kernel to learn n|n|, which it cannot extrapolate to a trial with wider excitation (docs/models.md).",
        min_length=1)
    actuator_inputs: list[str] | None = Field(None, description=(
        "The inputs that are actuators or control inputs (thruster speeds, PWM, thrust, rudder angle): the 2-weights "
        "kernel gives them one gamma, the velocities another. They must come last in `inputs`. None: every input "
        "that is not a body velocity of the kinematics table (u_mps ... r_radps, their _smooth and _meas forms)."))
    outputs: list[str] = Field(default_factory=lambda: ["udot_mps2", "vdot_mps2", "rdot_radps2"], min_length=1)
    models: list[str] = Field(
        default_factory=lambda: ["rbf_svr", "two_weights_svr", "wdse_svr", "gertler_hagen", "mcfarland_whitcomb",
                                 "fossen", "graybox_fossen"],
        description="The papers' five models, fossen (Fossen's 3-DOF model: M_RB from the vehicle, added mass, "
        "linear + |nu|nu damping, terms selected by held-out free-run error) and graybox_fossen (it plus a "
        "WDSE-SVR on its residual; docs/models.md). graybox and graybox_gh: the gray box on McFarland-Whitcomb "
        "or Gertler-Hagen.", min_length=1)
    folds: int = Field(5, ge=2, le=100)
    search: Literal["paper_grid", "fast"] = "fast"
    max_samples: int | None = Field(
        600, ge=10, le=1_000_000, description="The rows each search scores its candidates on: this many, evenly "
        "spaced in time "
        "over the block searched (its whole span of motion), so a search's cost does not grow with the trials' "
        "length; the final models are fitted on every train_test row. null: every row (a search's cost then grows "
        "as rows squared: hours on two 480-s trials). docs/models.md, 'A bounded search by default'.")
    svr_max_rows: int | None = Field(
        4000, ge=100, le=10_000_000, description="Every SVR fit of the train stage (CV folds, final models, a gray "
        "box's residual) uses at most this many of its rows, evenly spaced in time, with C scaled to them: a libsvm "
        "fit costs about the square of its rows and a free run its support vectors. null: every row (hours on a "
        "campaign of many trials). docs/models.md, 'Bounded final fits'.")
    screen_samples: int | None = Field(
        None, description="Successive halving over rows (fast search): each search screens its candidates "
        "on this many of its max_samples rows (evenly spaced in time), then scores its `survivors` best and the warm "
        "start on all of them. null (or >= max_samples): no row screen. Off by default: on the demo a search's cost "
        "is libsvm's iterations at large C, not its rows (docs/models.md, 'Successive halving').", ge=10, le=1_000_000)
    screen_folds: int | None = Field(
        2, ge=1, le=100, description="Successive halving over folds (fast search): each search screens its max_evals "
        "candidates on this many of its tuning_folds folds (spread over the block), then completes the other folds "
        "for its `survivors` best and the warm start, and keeps the best of those by the mean over all folds. null "
        "(or >= tuning_folds): every candidate on every fold. docs/models.md, 'Successive halving'.")
    survivors: int = Field(6, description="Successive halving: the screen's best candidates scored on every "
                           "row and fold (the warm start besides).", ge=1, le=10_000)
    iter_cap_ratio: float | None = Field(
        20.0, ge=1, le=1e6, description="Fast search: once five candidates are scored, a candidate's fits stop at "
        "this many times the median libsvm iterations of the search's fits so far (never below twice the best "
        "candidate's), so that no candidate costs far more than its search's median; a stopped fit is scored as it "
        "is and counted in the search's trace. null: only the absolute cap (1000 iterations per row). "
        "docs/models.md, 'Each candidate's cost is capped and reported'.")
    c_rate: float = Field(
        0.5, ge=0, le=1, description="The SVRs' C is chosen on a search fold's rows (C_rows in the tuning JSON) and "
        "the model fitted on n rows uses C (C_rows / n)^c_rate: libsvm's regularization 1/(2 C n) then falls as "
        "n^-c_rate (0: C kept as searched, regularization ~ 1/n; 1: regularization kept). docs/models.md.")
    seed: Seed = 0
    explicit_refine: bool = Field(
        False, description="Output-error refinement of the explicit models (Gertler-Hagen, McFarland-Whitcomb; not "
        "fossen, whose terms are already chosen by free-run error): "
        "from the WTLS fit, coefficients refined by minimizing the free-run velocity error over windows of "
        "refine_horizon_s (multiple shooting, RK4 at the grid step; kept only if it lowers that error).")
    refine_horizon_s: float = Field(2.0, gt=0, le=3600.0, description="explicit_refine: length of each free-run "
                                    "window (s, up to an hour).")
    tuning: Literal["nested", "split"] = Field(
        "nested", description="Where the SVRs' hyperparameters are searched. nested: on the rows each model is "
        "fitted on: in each CV fold on that fold's training blocks only (so the CV score stays unbiased), for the "
        "final model on the whole train_test block (the tune stage). split: the papers' protocol, on the tuning "
        "split (the first tuning_fraction of each trial) once, then fixed; on realistic trials that block is too "
        "short to rank hyperparameters the way the whole training set needs them (docs/models.md).")
    tuning_folds: int = Field(5, ge=2, le=100, description="CV folds inside each search's data (search score): "
                              "each candidate is scored on this many test blocks, or at most this many groups of "
                              "whole trials (tuning_cv; docs/models.md).")
    tuning_cv: Literal["auto", "blocked", "trials"] = Field(
        "blocked", description="How each search's folds cut its rows (the tune stage's, the nested CV's local "
        "searches, a gray box's residual verdict). blocked: tuning_folds contiguous blocks of the rows of all "
        "training trials together. trials: whole training trials held out (leave-one-trial-out; with more trials "
        "than tuning_folds, that many contiguous groups of trials), so a candidate is scored on a trial it was not "
        "fitted on. auto: trials where the search's rows come from two or more trials of at least 20 rows each, "
        "else blocked. docs/models.md, 'Searches that hold out whole trials', says why blocked is the default.")
    max_evals: int = Field(30, ge=1, le=10_000, description="Fast search: most candidates per model and output.")
    fold_evals: int | None = Field(
        8, description="Nested tuning with the fast search: each CV fold re-tunes on its own training rows "
        "by a local search of at most this many candidates started from the tune stage's optimum (steps of x2), "
        "each scored on the halving screen's folds (screen_folds), not a whole search. null: a whole search per "
        "fold (folds + 1 times the tune stage). docs/models.md.", ge=1, le=10_000)
    smooth_tolerance: float = Field(
        0.0, description="Fast search: pick the smoothest kernel (smallest gammas) scoring within this much "
        "tuning R² of the best (0: the best). Regularizes the choice on a short tuning block.", ge=0, le=1.0)
    residual_min_cv_r2: float | None = Field(
        0.0, description="Gray-box models: per output, the residual WDSE-SVR is kept only where its search's "
        "blocked-CV R² on the base's residual is above this by more than its standard error over the folds (0: "
        "better than a constant); elsewhere that output is "
        "the explicit base alone. The nested CV's folds apply it to their own search's score. null: always kept "
        "(docs/models.md, 'Gray box').", le=1.0)
    residual_fold_check: Literal["trials", "folds", "off"] = Field(
        "trials", description="Gray-box models: the train stage compares each gray box with its own base on every "
        "held-out training trial and every CV fold (card, Table III), and then keeps an output's residual only "
        "where that comparison says it helps: the mean test-R² gain above 0 by more than its standard error. "
        "trials: judged on the held-out trials (with fewer than two training trials, no residual is kept: a CV "
        "within one trial does not show that it carries to the next); folds: on the CV folds (a tie dropped); off: "
        "recorded only. Where dropped, the saved model, its CV and final-check scores and its interval are the "
        "base's (docs/models.md, 'Gray box').")
    selection: Literal["best", "one_se"] = Field(
        "best", description="Fast search: which candidate to keep. best: the highest mean fold R². one_se: the "
        "smoothest kernel within one standard error of it (the one-standard-error rule; docs/models.md).")
    n_jobs: int | Literal["auto"] = Field(
        "auto", description="Workers for the study's independent tasks: the tune stage's search chains (per output, "
        "per gray box and output) and the train stage's CV folds and final fits (per model). auto (or -1): every "
        "usable core (AUVID_JOBS where set; every worker of a Dask cluster under --scheduler); 1: serial. The "
        "outputs are the same bytes whatever the number (docs/user-guide.md, 'Parallel runs').")

    @field_validator("n_jobs")
    @classmethod
    def _workers(cls, n_jobs: int | str) -> int | str:
        return _n_jobs(n_jobs)

    @field_validator("models")
    @classmethod
    def _models_known(cls, models: list[str]) -> list[str]:
        _known(models, COUPLED_MODELS, "coupled model")
        return _unique_safe_names(models, "model")

    @model_validator(mode="after")
    def _explicit_outputs(self) -> CoupledParams:
        # the explicit models (and gray boxes on them) predict [udot vdot rdot] as one system, column by column:
        # another count fails deep in the train stage, another order would fit each equation to the wrong target
        explicit = [m for m in self.models if m in EXPLICIT_MODELS or m.startswith("graybox")]
        if explicit and self.outputs != PLANAR_OUTPUTS:
            raise checks.KeyedError("outputs", f"coupled.models {explicit} predict {PLANAR_OUTPUTS} in this order: "
                                    f"set coupled.outputs to it (not {self.outputs}), or keep only SVRs in "
                                    "coupled.models")
        return self

    @model_validator(mode="after")
    def _input_groups(self) -> CoupledParams:
        actuators = self.actuators()
        unknown = [c for c in actuators if c not in self.inputs]
        if unknown:
            raise ValueError(f"actuator_inputs {unknown} are not in coupled.inputs {self.inputs}")
        first = len(self.inputs) - len(actuators)
        if set(self.inputs[first:]) != set(actuators):
            velocities = [c for c in self.inputs if c not in actuators]
            raise ValueError(f"the kernels take the velocities first, then the actuators: order coupled.inputs as "
                             f"{velocities + [c for c in self.inputs if c in actuators]} (velocities {velocities}, "
                             f"actuators {actuators})")
        return self

    def actuators(self) -> list[str]:
        """The actuator / control inputs: ``actuator_inputs``, or the inputs that are not body velocities."""
        if self.actuator_inputs is not None:
            return list(self.actuator_inputs)
        return [c for c in self.inputs if not _BODY_VELOCITY.match(c)]

    def n_velocity_inputs(self) -> int:
        """How many leading inputs are velocities (the 2-weights and WDSE kernels' first group)."""
        return len(self.inputs) - len(self.actuators())


def _n_jobs(n_jobs: int | str) -> int | str:
    if n_jobs == "auto":
        return n_jobs
    if n_jobs == 0 or n_jobs < -1 or n_jobs > MAX_WORKERS:  # type: ignore[operator]
        raise ValueError(f"n_jobs must be a number of workers (1 to {MAX_WORKERS}), -1 or auto for all cores, not "
                         f"{n_jobs}")
    return n_jobs


class DecoupledParams(Frozen):
    dofs: list[str] = Field(default_factory=lambda: ["u", "v", "r"], min_length=1)
    models: list[str] = Field(default_factory=lambda: ["ls", "mlp", "krr", "svr", "gp"], min_length=1)
    folds: int = Field(5, ge=2, le=100)
    search: Literal["paper_grid", "fast"] = "fast"
    gp_max_samples: int = Field(
        500, ge=50, le=20_000, description="GP training points, chosen evenly in velocity (a fit costs O(n^3); "
        "bench/gp.py).")
    gp_warp: Literal["signed_square", "none"] = Field(
        "signed_square", description="GP inputs: (nu, nu|nu|) with a length scale each (default), or nu alone (the "
        "paper's RBF, whose band misses the truth around nu = 0; docs/models.md).")
    seed: Seed = 0
    max_samples: int | None = Field(
        3000, ge=50, le=10_000_000, description="Each split thinned to this many rows by an even time stride (None: "
        "all rows).")
    curve_points: int = Field(5, ge=2, le=50, description="Training sizes on each learning curve.")
    trials: dict[str, list[str]] = Field(
        default_factory=dict, description="Per DOF, the trials its damping is learned from (paper 001: experiments "
        "that excite that DOF alone, e.g. pipeline.sim Controls(excite='surge')); DOFs not named use every trial.")
    intercept: list[str] = Field(
        default_factory=lambda: ["w"], description="DOFs whose ls model fits a constant beside d_l and d_q: the "
        "static force the damping target still holds. For w (heave) it is the net buoyancy that the vehicle's "
        "buoyancy_N leaves out (all of B - W with buoyancy_N: null), and the study reports B - W with its SD; "
        "[]: paper 001's model, no constant (docs/models.md).")
    n_jobs: int | Literal["auto"] = Field(
        "auto", description="Workers for the study's (DOF, model) units, each a search, a CV and a final fit. auto "
        "(or -1): every usable core (AUVID_JOBS where set; every worker of a Dask cluster under --scheduler); 1: "
        "serial. The outputs are the same bytes whatever the number (docs/user-guide.md, 'Parallel runs').")

    @field_validator("n_jobs")
    @classmethod
    def _workers(cls, n_jobs: int | str) -> int | str:
        return _n_jobs(n_jobs)

    @field_validator("dofs")
    @classmethod
    def _dofs_known(cls, dofs: list[str]) -> list[str]:
        _known(dofs, DOFS, "DOF")
        return _unique_safe_names(dofs, "DOF")

    @field_validator("models")
    @classmethod
    def _models_known(cls, models: list[str]) -> list[str]:
        return _decoupled_models(models)

    @field_validator("intercept")
    @classmethod
    def _intercept_dofs(cls, dofs: list[str]) -> list[str]:
        _known(dofs, DOFS, "DOF")
        return _unique_safe_names(dofs, "DOF")

    @field_validator("trials")
    @classmethod
    def _trials_per_dof(cls, trials: dict[str, list[str]]) -> dict[str, list[str]]:
        _dof_keys(trials)
        for dof, names in trials.items():
            try:
                _unique_safe_names(names, "trial")
            except checks.KeyedError as err:
                raise checks.KeyedError(f"{dof}.{err.key}", str(err)) from None
        return trials


def _decoupled_models(models: list[str]) -> list[str]:
    _known(models, DECOUPLED_MODELS, "decoupled model")
    return _unique_safe_names(models, "model")


class SimulateParams(Frozen):
    horizons_s: list[Seconds] = Field(default_factory=lambda: [1.0, 5.0, 10.0], min_length=1)
    outage_windows_s: list[Seconds] = Field(default_factory=lambda: [10.0, 30.0, 60.0])
    divergence_factor: float = Field(
        10.0, gt=1, le=1000.0, description="A rollout beyond this many times the measured range diverged (1 to 1000: "
        "further out, the states overflow before the bound is met).")
    method: Literal["rk4", "euler"] = Field("rk4", description="Fixed-step integrator at the grid rate (ZOH inputs).")
    band_samples: int = Field(32, ge=0, le=1000,
                              description="GP posterior functions rolled out for the 2-sigma band (0: none).")
    models: list[str] | None = Field(None, description="Decoupled models to simulate (None: every fitted one).")
    seed: Seed = 0

    @field_validator("models")
    @classmethod
    def _models_known(cls, models: list[str] | None) -> list[str] | None:
        return None if models is None else _decoupled_models(models)


class Params(Frozen):
    ingest: IngestParams = IngestParams()
    sync: SyncParams = SyncParams()
    differentiate: DifferentiateParams = DifferentiateParams()
    features: FeaturesParams = FeaturesParams()
    coupled: CoupledParams = CoupledParams()
    decoupled: DecoupledParams = DecoupledParams()
    simulate: SimulateParams = SimulateParams()

    @model_validator(mode="after")
    def _below_nyquist(self) -> Params:
        """The band limit's frequencies below the grid's Nyquist frequency (the differentiate stage checks it
        again on the grid it gets)."""
        nyquist = self.sync.rate_hz / 2
        d = self.differentiate
        for i, f in enumerate(d.notch_hz):
            if not f + d.notch_width_hz / 2 < nyquist:
                raise checks.KeyedError(f"differentiate.notch_hz.{i}", f"a notch at {f:g} Hz (width "
                                        f"{d.notch_width_hz:g} Hz) is not below the grid's Nyquist frequency "
                                        f"{nyquist:g} Hz (sync.rate_hz / 2)")
        if d.max_hz is not None and not d.max_hz < nyquist:
            raise checks.KeyedError("differentiate.max_hz", f"max_hz {d.max_hz:g} Hz is not below the grid's Nyquist "
                                    f"frequency {nyquist:g} Hz (sync.rate_hz / 2)")
        return self
