"""``config_hash``: the sha256 that names a config in every output's provenance.

Light on purpose (no pydantic): :mod:`pipeline.ingest` hashes a snapshot's views with it as it hashes the models.
"""

from __future__ import annotations

import hashlib
from typing import Any

from pipeline.tableio import canonical_json


def config_hash(model: Any) -> str:
    """sha256 of the canonical JSON of a config model (or of a :class:`~pipeline.config.snapshot.ConfigView` of
    one)."""
    return hashlib.sha256(canonical_json(model.model_dump(mode="json")).encode()).hexdigest()
