"""``<root>/plan.yaml``: the root's remembered plan (:class:`~carlaocc.schemas.plan.Plan`), in
YAML a person can read and edit. The one place that reads and writes it (load / save / exists)."""

from __future__ import annotations

import yaml
from pydantic import ValidationError

from carlaocc.catalog.store import PLAN_FILE, Store, StoreError
from carlaocc.schemas.plan import Plan

HEADER = """\
# The plan this dataset root is built to: `carlaocc run`, `status`, `stage` and `export` without
# options use it; an option changes its key and `carlaocc run` remembers the new plan here.
# `carlaocc run --default-plan` (make dataset PLAN=default) goes back to the default plan.
# voxel_sizes: metres; slice: the first limit_frames frames (null: all) of the sequences
# matching the fnmatch patterns in sequences ([]: all); config: the dataset config
# (`carlaocc config` documents it), taxonomy (the label table) included.
"""


class PlanStore:
    """The remembered plan of one dataset root."""

    def __init__(self, store: Store) -> None:
        self.store = store

    @property
    def url(self) -> str:
        return self.store.uri(PLAN_FILE)

    def exists(self) -> bool:
        return self.store.exists(PLAN_FILE)

    def load(self) -> Plan | None:
        """The remembered plan, None when the root has none; StoreError naming the file when it
        cannot be read as a plan (and how to get past it)."""
        try:
            if not self.exists():
                return None
            text = self.store.read_bytes(PLAN_FILE).decode()
        except (OSError, UnicodeDecodeError, StoreError) as exc:
            raise StoreError(f"{self.url}: cannot read the remembered plan ({exc}); fix or delete it, or "
                             f"run with --default-plan") from None
        try:
            data = yaml.safe_load(text)
        except yaml.YAMLError as exc:
            raise StoreError(f"{self.url}: not YAML ({str(exc).splitlines()[0]}); fix or delete it, or run "
                             f"with --default-plan") from None
        try:
            return Plan.model_validate(data or {})
        except ValidationError as exc:
            err = exc.errors()[0]
            loc = ".".join(str(p) for p in err["loc"]) or "(top level)"
            msg = "unknown key" if err["type"] == "extra_forbidden" else err["msg"].removeprefix("Value error, ")
            raise StoreError(f"{self.url}: {loc}: {msg}; fix or delete it, or run with --default-plan") from None

    def save(self, plan: Plan) -> str:
        """Write the plan (atomically); returns its fingerprint."""
        body = yaml.safe_dump(plan.model_dump(mode="json"), sort_keys=False, default_flow_style=None, width=100)
        return self.store.write_bytes(PLAN_FILE, (HEADER + body).encode())


__all__ = ["PlanStore"]
