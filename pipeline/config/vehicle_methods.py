"""The methods a vehicle config answers, written once for the model (:class:`~pipeline.config.vehicle.Vehicle`)
and for a snapshot's view of it (:class:`~pipeline.config.snapshot.VehicleView`). No pydantic here: the view is
read without it."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

from pipeline.config.checks import applies_to


class VehicleMethods:
    """Paths, signal names and per-trial overrides of a vehicle config.

    A class using it has ``streams`` and ``_base_dir``, and says where its overrides come from
    (:meth:`override_keys`) and how a trial's overrides are applied (:meth:`_apply_overrides`).
    """

    if TYPE_CHECKING:  # declared for type checkers only: pydantic must not take them for fields
        _base_dir: Path
        _source: str | None
        streams: dict[str, Any]

    def config_file(self) -> str | None:
        """The YAML file the config was loaded from (None: built in memory), for errors found after loading."""
        return self._source

    def source_key(self, topic: str | None, field: str | None = None) -> str | None:
        """The config key that names ``topic`` (a stream's topic or file) or, with ``field``, the field of one of
        its signals: ``streams.dvl.topic``, ``streams.dvl.signals.dvl_x_mps.field``; None if no stream does."""
        for name, stream in self.streams.items():
            if topic is not None and topic in (stream.topic, stream.file):
                for signal, source in stream.signals.items():
                    if field is not None and source.field == field:
                        return f"streams.{name}.signals.{signal}.field"
                return f"streams.{name}.{'topic' if stream.topic == topic else 'file'}"
        return None

    def resolve(self, relative: str | Path) -> Path:
        """A path from the config (a thrust table), relative to the vehicle file's directory."""
        return self._base_dir / relative

    def signal_names(self) -> list[str]:
        """Every signal of every stream, the mixed motor PWMs (a stream's ``mixing.outputs``) included."""
        return [name for stream in self.streams.values()
                for name in [*stream.signals, *(stream.mixing.outputs if stream.mixing is not None else ())]]

    def override_keys(self) -> dict[str, dict[str, dict[str, Any]]]:
        """Every trial override as given: ``{pattern: {stream: {key: value}}}``, in config order."""
        raise NotImplementedError

    def trial_overrides(self, trial: str) -> dict[str, dict[str, Any]]:
        """The overrides that apply to ``trial``: ``{pattern: {stream: {key: value}}}``, in config order."""
        return {pattern: given for pattern, given in self.override_keys().items() if applies_to(pattern, trial)}

    def for_trial(self, trial: str) -> Any:
        """This vehicle with the streams as ``trial`` has them (its ``trials`` overrides applied); itself if none
        applies."""
        if not any(self.trial_overrides(trial).values()):
            return self
        return self._apply_overrides(trial)

    def _apply_overrides(self, trial: str) -> Any:
        raise NotImplementedError
