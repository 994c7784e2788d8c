"""Run configuration: tracker preset and overrides, flag thresholds, seed.

Precedence is defaults < config file < command-line flags. The YAML file has
up to five top-level keys::

    preset: fast          # a tracker preset name
    seed: 0
    tracker:              # any TrackerParams field
      n_particles: 400
    flags:                # any FlagParams field
      threshold: 0.6
    failure_model: my_model.json   # a refitted failure model (default: the one shipped)

An unknown key anywhere is an error naming the closest valid key.
"""

from __future__ import annotations

import dataclasses
import difflib
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Mapping

import yaml

from annotator.errors import EXIT_VALUE
from annotator.flagging import FlagParams
from annotator.text_input import read_given_file
from sptpt import TrackerParams, params_from_mapping
from sptpt import preset as get_preset

if TYPE_CHECKING:
    from annotator.failure.model import FailureModel

__all__ = ["DEFAULT_PRESET", "RunConfig", "ConfigError", "load_config_file", "resolve_config"]

#: The tracker preset of a run that names none: ``fused`` (``robust`` with NanoTrack v2 beside it), success AUC
#: 0.608 +- 0.003 on the unseen ../shared/otb_extra over 3 seeds against ``robust``'s 0.389 +- 0.009, and fewer
#: human seconds to correct there with the simulated reviewer (benchmarks/RESULTS.md, "The fused preset").
#: ``robust`` is the same tracker without a learned part; ``paper`` follows docs/design/tracker.md, to reproduce the
#: paper.
DEFAULT_PRESET = "fused"

_TOP_LEVEL = ("preset", "seed", "tracker", "flags", "failure_model")


class ConfigError(ValueError):
    """A configuration file or value that cannot be used; the message names the source.

    ``exit_code`` is the tool's code for it: 4 (invalid value) by default, 3
    when the file itself is missing or unreadable.
    """

    def __init__(self, message: str, exit_code: int = EXIT_VALUE) -> None:
        super().__init__(message)
        self.exit_code = exit_code


@dataclass(frozen=True)
class RunConfig:
    """Everything that decides a run's numbers.

    :func:`resolve_config` builds one, from the defaults, a config file's values and the command line's.

    Attributes
    ----------
    preset : str
        The preset the tracker parameters started from.
    tracker : TrackerParams
        The tracker's parameters.
    flags : FlagParams
        How failure probabilities become flags.
    seed : int
        The run's seed; each track's generator derives from it (:func:`seed_for_track`).
    failure_model : str or None
        Path of a failure-model JSON; None: the one shipped for the kind of run.
    """

    preset: str
    tracker: TrackerParams
    flags: FlagParams
    seed: int
    failure_model: str | None = None

    def to_dict(self) -> dict[str, Any]:
        return {
            "preset": self.preset,
            "seed": self.seed,
            "tracker": self.tracker.to_dict(),
            "flags": dataclasses.asdict(self.flags),
            "failure_model": self.failure_model,
        }

    def load_failure_model(self) -> FailureModel:
        """The model that scores this run's frames: the file given, else the one shipped for this kind of run (runs
        with the NanoTrack guide fail differently and have a model of their own)."""
        from annotator.failure.model import load_model

        return load_model(self.failure_model, guided=self.tracker.uses_guide)


def load_config_file(path: str | Path) -> dict[str, Any]:
    """Read a YAML config file into a mapping, with errors naming the file.

    Parameters
    ----------
    path : str or Path
        A YAML file with ``preset``, ``seed``, ``tracker`` and ``flags`` keys (each optional).

    Returns
    -------
    dict
        The file's values, for :func:`resolve_config`'s ``file_values``.

    Raises
    ------
    ConfigError
        The file is missing or unreadable (exit 3), not YAML or not a mapping (4); the message names the file.
    """
    path = Path(path)
    text = read_given_file(path, what="config file", expected="a YAML file with preset, seed, tracker and flags keys",
                           error=ConfigError)
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f":{mark.line + 1}" if mark is not None else ""
        raise ConfigError(f"config file {path}{where} is not valid YAML: {getattr(exc, 'problem', exc)}") from None
    return _as_mapping(data, f"config file {path} must hold a mapping of {', '.join(_TOP_LEVEL)}")


def _unknown(kind: str, key: str, valid: list[str], source: str) -> ConfigError:
    close = difflib.get_close_matches(str(key), valid, n=1)
    hint = f"did you mean {close[0]!r}?" if close else f"valid keys: {', '.join(valid)}"
    return ConfigError(f"{source}: unknown {kind} {key!r}: {hint}")


def resolve_config(
    file_values: Mapping[str, Any] | None = None,
    *,
    source: str = "config",
    preset: str | None = None,
    seed: int | None = None,
    tracker_overrides: Mapping[str, Any] | None = None,
    flag_overrides: Mapping[str, Any] | None = None,
    failure_model: str | Path | None = None,
) -> RunConfig:
    """Combine defaults, a config file's values and command-line values (highest precedence).

    Parameters
    ----------
    file_values : mapping, optional
        A config file's values (:func:`load_config_file`): ``preset``, ``seed``, ``tracker``, ``flags``,
        ``failure_model``.
    source : str
        What the values are called in error messages (the config file's path).
    preset : str, optional
        A preset name (``paper``, ``fast``, ``robust``, ``fused``); by default the file's, else the default preset.
    seed : int, optional
        The run's seed; by default the file's, else 0.
    tracker_overrides, flag_overrides : mapping, optional
        Tracker parameters and flag settings over the preset's and the file's.
    failure_model : str or Path, optional
        A failure-model JSON file; by default the one shipped for the kind of run.

    Returns
    -------
    RunConfig
        Every setting that decides the run's numbers, checked.

    Raises
    ------
    ConfigError
        An unknown key (with the closest valid one), a value of the wrong type or range, or a combination the
        tracker refuses.

    Examples
    --------
    >>> from annotator import resolve_config
    >>> config = resolve_config({"seed": 3}, preset="fast")
    >>> config.preset, config.seed
    ('fast', 3)
    """
    file_values = dict(file_values or {})
    for key in file_values:
        if key not in _TOP_LEVEL:
            raise _unknown("top-level key", key, list(_TOP_LEVEL), source)
    preset_name = preset or file_values.get("preset") or DEFAULT_PRESET
    seed_value = seed if seed is not None else file_values.get("seed", 0)
    if isinstance(seed_value, bool) or not isinstance(seed_value, int) or seed_value < 0:
        raise ConfigError(f"{source}: seed must be a non-negative integer, got {seed_value!r}")
    try:
        base = get_preset(str(preset_name))
        tracker = params_from_mapping(_mapping(file_values.get("tracker"), "tracker", source), base)
        tracker = params_from_mapping(dict(tracker_overrides or {}), tracker)
        _check_tracker_accepts(tracker)
    except ConfigError:
        raise  # already names its source
    except ValueError as exc:
        raise ConfigError(f"{source}: {exc}") from None
    flag_values = {**_mapping(file_values.get("flags"), "flags", source), **dict(flag_overrides or {})}
    valid = [f.name for f in dataclasses.fields(FlagParams)]
    for key in flag_values:
        if key not in valid:
            raise _unknown("flag parameter", key, valid, source)
    defaults = FlagParams()
    # Settings typed ``X | None`` take null (YAML ``~``/``null``, run.json's null): "not set", or "never".
    nullable = {f.name for f in dataclasses.fields(FlagParams) if "None" in str(f.type)}
    try:
        # Any: each value is made like its field's default at run time (_like), which no static type follows.
        values: dict[str, Any] = {k: None if v is None and k in nullable else _like(getattr(defaults, k), v, k, source)
                                  for k, v in flag_values.items()}
        flags = dataclasses.replace(defaults, **values)
    except ConfigError:
        raise  # already names its source
    except ValueError as exc:
        raise ConfigError(f"{source}: {exc}") from None
    model_path = failure_model if failure_model is not None else file_values.get("failure_model")
    if model_path is not None:
        model_path = str(Path(model_path).resolve())
        check_failure_model(model_path)
    return RunConfig(preset=str(preset_name), tracker=tracker, flags=flags, seed=int(seed_value),
                     failure_model=model_path)


def check_failure_model(path: str) -> None:
    """Load a failure-model file once, so that a bad one fails before any tracking, not after it: a
    :class:`ConfigError` naming it, exit 3 when it is missing, 4 when it cannot be used."""
    from annotator.failure.model import FailureModelError, load_model

    try:
        load_model(path)
    except FailureModelError as exc:
        raise ConfigError(str(exc), exc.exit_code) from None


def _check_tracker_accepts(params: TrackerParams) -> None:
    """Raise the tracker's own ValueError for combinations only it checks (e.g. a superpixel rank above the
    superpixel count), so that they are configuration errors now rather than failures once a run has started."""
    import sptpt  # its tracker modules load on first use: only a resolved config needs them

    sptpt.check_params(params)


def _mapping(value: Any, name: str, source: str) -> dict[str, Any]:
    return _as_mapping(value, f"{source}: '{name}' must be a mapping of parameter names to values")


def _as_mapping(value: Any, expected: str) -> dict[str, Any]:
    """``value`` as a mapping: empty for None (an empty YAML block), else the ConfigError ``expected, got TYPE``."""
    if value is None:
        return {}
    if not isinstance(value, dict):
        raise ConfigError(f"{expected}, got {type(value).__name__}")
    return value


def _like(default: Any, value: Any, name: str, source: str) -> Any:
    if value is None and default is None:  # an optional setting left unset (run.json records it as null)
        return None
    if isinstance(default, bool) or isinstance(value, bool):
        raise ConfigError(f"{source}: flag parameter {name}={value!r} is invalid: expected a number")
    if isinstance(default, int):
        if not (isinstance(value, int) or (isinstance(value, float) and value.is_integer())):
            raise ConfigError(f"{source}: flag parameter {name}={value!r} is invalid: expected an integer")
        return int(value)
    if not isinstance(value, (int, float)):
        raise ConfigError(f"{source}: flag parameter {name}={value!r} is invalid: expected a number")
    return float(value)
