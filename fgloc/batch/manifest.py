"""The batch manifest: which scenarios, which methods, which configuration.

A manifest is a TOML file (paths relative to the manifest's directory)::

    scenarios = ["recordings/*", "/data/site7/rec-2024-*"]   # directories; globs (*, ?, [], **)
    methods = ["icp", "filter-sicp"]                           # keys of fgloc.pipeline.METHODS
    config = "fgloc.toml"                                      # optional fgloc config file
    ignore_yaw_guess = false                                   # optional: global yaw search

    [overrides]                                                # optional: config keys on top
    coarse.doppler_min = 0.6

Every (scenario, method) pair is one :class:`Job`. A pattern that matches no directory, an
unknown method or a bad config key is an :class:`fgloc.errors.InputError` naming the manifest
and the key.
"""

from __future__ import annotations

import glob
import hashlib
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from fgloc.config import Config, from_dict, load_config, read_toml, to_dict
from fgloc.errors import InputError


@dataclass
class _ManifestFile:
    """The manifest as written (validated by fgloc.config.from_dict)."""

    scenarios: list[str] = field(default_factory=list)
    methods: list[str] = field(default_factory=list)
    config: str | None = None
    ignore_yaw_guess: bool = False
    overrides: dict = field(default_factory=dict)


@dataclass(frozen=True)
class Job:
    """One localization of a batch: ``method`` on the scenario directory ``scenario``.

    label: the scenario's unique name within the batch; key ``<label>/<method>`` names the
    job and its output directory ``<out>/jobs/<label>/<method>``. config: the full fgloc
    configuration as a plain dict (picklable, hashed into :attr:`fingerprint`).
    """

    scenario: str
    label: str
    method: str
    config: dict[str, Any]
    ignore_yaw_guess: bool = False

    @property
    def key(self) -> str:
        return f"{self.label}/{self.method}"

    @property
    def fingerprint(self) -> str:
        """Hash of everything that determines the job's result (scenario path, method, config,
        yaw-guess flag); a finished job with another fingerprint is run again."""
        doc = json.dumps(
            [self.scenario, self.method, self.config, self.ignore_yaw_guess], sort_keys=True
        )
        return hashlib.sha256(doc.encode()).hexdigest()[:16]


@dataclass
class Manifest:
    path: Path
    scenarios: list[Path]
    methods: list[str]
    config: Config
    ignore_yaw_guess: bool = False

    def jobs(self) -> list[Job]:
        """Every (scenario, method) job, scenario-major, in manifest order."""
        cfg = to_dict(self.config)
        labels = scenario_labels(self.scenarios)
        return [
            Job(str(s), lab, m, cfg, self.ignore_yaw_guess)
            for s, lab in zip(self.scenarios, labels)
            for m in self.methods
        ]


def read_manifest(path: str | Path) -> Manifest:
    """Read and validate a manifest; expand its scenario globs (sorted, duplicates dropped)."""
    from fgloc.pipeline import METHODS

    p = Path(path)
    raw = from_dict(_ManifestFile, read_toml(p), p)
    base = p.parent
    if not raw.scenarios:
        raise InputError(p, "expected a non-empty list of scenario directories or globs",
                         field="scenarios")
    if not raw.methods:
        raise InputError(p, f"expected a non-empty list of methods ({', '.join(METHODS)})",
                         field="methods")
    for k, m in enumerate(raw.methods):
        if m not in METHODS:
            raise InputError(p, f"unknown method {m!r} (available: {', '.join(METHODS)})",
                             field=f"methods[{k}]")
    if len(set(raw.methods)) != len(raw.methods):
        raise InputError(p, "a method is listed twice", field="methods")
    scenarios: list[Path] = []
    for k, pattern in enumerate(raw.scenarios):
        full = Path(pattern).expanduser()
        full = full if full.is_absolute() else base / full
        found = sorted(Path(m).resolve() for m in glob.glob(str(full), recursive=True))
        dirs = [d for d in found if d.is_dir()]
        if not dirs:
            raise InputError(p, f"{pattern!r} matches no directory (relative to {base})",
                             field=f"scenarios[{k}]")
        scenarios.extend(d for d in dirs if d not in scenarios)
    config = Config()
    if raw.config is not None:
        cfg_path = Path(raw.config).expanduser()
        config = load_config(cfg_path if cfg_path.is_absolute() else base / cfg_path)
    if raw.overrides:
        merged = _deep_merge(to_dict(config), raw.overrides)
        config = from_dict(Config, merged, p, prefix="overrides.")
    return Manifest(p, scenarios, list(raw.methods), config, raw.ignore_yaw_guess)


def _deep_merge(base: dict[str, Any], top: dict[str, Any]) -> dict[str, Any]:
    """``base`` with the keys of ``top`` replaced, tables merged key by key."""
    out = dict(base)
    for k, v in top.items():
        both_tables = isinstance(v, dict) and isinstance(out.get(k), dict)
        out[k] = _deep_merge(out[k], v) if both_tables else v
    return out


def scenario_labels(paths: list[Path]) -> list[str]:
    """A unique, file-name-safe label per scenario directory: the shortest tail of its path
    that no other scenario shares, parts joined by ``__`` (``siteA__rec1``)."""
    parts = [p.parts[1:] if p.is_absolute() else p.parts for p in paths]
    labels = []
    for mine in parts:
        for n in range(1, len(mine) + 1):
            tail = mine[-n:]
            if sum(1 for other in parts if other[-n:] == tail) == 1:
                break
        labels.append("__".join(tail))
    return labels
