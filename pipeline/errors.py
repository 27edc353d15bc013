"""One small error hierarchy. Build the message, then raise; say what was expected and what was found."""

from __future__ import annotations

from pathlib import Path


class PipelineError(Exception):
    """Base of every error the pipeline raises on purpose.

    ``file``, ``topic`` and ``field`` say where the problem is; they are kept as attributes so that a batch
    run can put them in its quarantine entry, and they are prefixed to the message so a user sees them.
    """

    def __init__(
        self,
        message: str,
        *,
        file: str | Path | None = None,
        topic: str | None = None,
        field: str | None = None,
    ) -> None:
        self.reason = message
        self.file = str(file) if file is not None else None
        self.topic = topic
        self.field = field
        where = []
        if self.file is not None:
            where.append(self.file)
        if topic is not None:
            where.append(f"topic {topic!r}")
        if field is not None:
            where.append(f"field {field!r}")
        super().__init__(f"{': '.join(where)}: {message}" if where else message)

    def as_dict(self) -> dict[str, str | None]:
        """Structured form for reports and quarantine entries."""
        return {
            "error": type(self).__name__,
            "reason": self.reason,
            "file": self.file,
            "topic": self.topic,
            "field": self.field,
        }


class ConfigError(PipelineError):
    """A vehicle config or params file is invalid (names the file and the key)."""


class IngestError(PipelineError):
    """A log cannot be read, or a configured topic / field is absent."""


class SchemaError(PipelineError):
    """A table does not have the columns, types or metadata a stage expects."""


class SyncError(PipelineError):
    """Streams cannot be put on a common grid (no overlap, no valid segment, ...)."""


class ModelError(PipelineError):
    """Model fitting, search or evaluation cannot proceed (too little data, leakage, divergence)."""


class RunRootBusy(PipelineError):
    """Another auvid command holds the run directory's lock (a usage error: exit 2, nothing done)."""
