"""What every bench section is given: the inputs, a scratch folder, the mode, and
what earlier sections left for later ones (the built sample, the scene build time)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path


@dataclass
class Context:
    sources: Path          # the user's sources folder (never written)
    out: Path              # the user's build folder: only reports/ is written
    work: Path             # scratch folder, deleted at the end
    quick: bool
    shared: dict = field(default_factory=dict)

    def pick(self, quick, full):
        """The quick-mode or full-mode value of a setting."""
        return quick if self.quick else full

    @property
    def built(self) -> Path | None:
        """A complete build of the sample (from the build section), or None."""
        return self.shared.get("built")

    def sample_build(self) -> Path:
        """The build section's sample build, for a section that needs it: RuntimeError
        when there is none."""
        if self.built is None:
            raise RuntimeError("no built sample (the build section failed)")
        return self.built
