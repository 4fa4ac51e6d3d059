"""The part of :class:`igdrivsim.pipeline.stages.Pipeline` that runs after the stages: the report
copied into ``PAPER`` with the provenance of the stages behind each file, the run's wall time
across invocations, the results page and the PDF."""

from __future__ import annotations

import shutil
import threading
import time
from pathlib import Path

from igdrivsim.io import atomic_copy, atomic_write_json, read_json
from igdrivsim.names import METHODS
from igdrivsim.pipeline.runner import REPO_ROOT, StageError
from igdrivsim.report import provenance
from igdrivsim.training.methods import get_method

PAPER_SOURCES = ("main.tex", "findings.tex", "references.bib", "Makefile")
# how often a running invocation writes its wall time so far to wall.json: an invocation killed
# outright (out of memory, a closed session) still counts, up to this much, in the provenance
WALL_EVERY_S = 60.0


class Publisher:
    """The report's publication and the run's wall time (the pipeline provides the fields)."""

    def write_results(self) -> None:
        """The default run (report in the repository's paper/): docs/results.md and the
        README's results block, from the published tables and their provenance."""
        if self.default_paper and (self.paper / "tables" / "summary.csv").is_file():
            from igdrivsim.report.results_doc import write_markdown  # lazy: pandas

            write_markdown(self.paper, REPO_ROOT / "docs" / "results.md", REPO_ROOT / "README.md")

    @property
    def staged(self) -> Path:
        """Where the report stages write; :meth:`publish` copies it into ``PAPER``."""
        return self.work / "report"

    @property
    def kind(self) -> str:
        """``methods`` for a run with taught methods (it owns Table II), else ``default``."""
        return "methods" if any(get_method(m).teacher for m in self.methods) else "default"

    def command_text(self) -> str:
        """The ``reproduce.sh`` command line that gives this pipeline (canonical order)."""
        args: list[str] = []
        if self.profile.name != "laptop":
            args += ["--profile", self.profile.name]
        if self.train_data is not None:
            args += ["--data", str(self.train_data), str(self.val_data)]
        if not self.default_paper:
            args += ["--out", str(self.work)]
        if tuple(self.settings) != tuple(self.profile.settings):
            args += ["--obs", ",".join(self.settings)]
        if tuple(self.methods) != tuple(METHODS):
            args += ["--methods", ",".join(self.methods)]
        args += [a for override in self.overrides for a in ("--set", override)]
        if self.samples_given:
            args += ["--samples", *self.samples_given]
        return provenance.command_line(args)

    def publish(self) -> list[str]:
        """Copy the report into ``PAPER`` with its provenance (when the report ran or a file
        is missing there), each file naming the code of the stages behind it as stamped."""
        missing = [r for r in provenance.outputs(self.staged) if not (self.paper / r).exists()]
        if not {"report", "real_logs", "reactive"} & self.ran and not missing:
            return []
        updates = self.training_config().training.num_updates
        entry = provenance.Entry(
            command=self.command_text(), run=self.kind, profile=self.profile.name,
            updates=updates, commit="unknown",  # each file's: its stages' (with_stages)
            device=self.trained_on(), wall_s=round(self.wall_seconds()), date=provenance.today(),
            note=provenance.competence_note(self.profile.name, updates))
        stamped = [s for s in self.stamped_stages() if self.of_this_run(s)]
        code = {s: self.stamped_code(s) for s in stamped}
        published = provenance.publish(self.staged, self.paper, entry, lambda rel: {
            s: code[s] for s in provenance.stages_behind(rel, stamped)})
        self._say(f"publish: {len(published)} files in {self.paper} (provenance: "
                  f"{self.paper / provenance.FILE})")
        return published

    def wall_seconds(self) -> float:
        """This run's wall time over its invocations, kept per kind of run (the default run and
        the taught methods' share a work folder)."""
        if self._walls_before is None:  # read once: this invocation rewrites the file
            self._walls_before = self._walls()
        return self._walls_before.get(self.kind, 0.0) + time.time() - self.started

    def _walls(self) -> dict[str, float]:
        record = read_json(self.work / "wall.json", {})
        try:
            return {str(k): float(v) for k, v in record.items()}
        except (ValueError, TypeError):
            return {}

    def _record_wall(self) -> None:
        walls = self._walls() | {self.kind: round(self.wall_seconds(), 1)}
        atomic_write_json(self.work / "wall.json", walls)

    def trained_on(self) -> str:
        """Where this run's training stages ran: one machine, or each machine with its parts."""
        where: dict[str, list[str]] = {}
        for path in sorted((self.work / "stages").glob("train_*.json")):
            if self.of_this_run(path.stem):
                where.setdefault(self.stamped_device(path.stem), []).append(
                    path.stem.removeprefix("train_"))
        if len(where) <= 1:
            return next(iter(where), self.device_text)
        return "; ".join(f"{device} ({', '.join(parts)})" for device, parts in where.items())

    def of_this_run(self, stage: str) -> bool:
        """A stage of this run: not the training or evaluation of another run's methods."""
        part = stage.removeprefix("train_").removeprefix("evaluate_").removesuffix("_idm")
        return part in (stage, "references") or any(
            part == m or part.startswith(f"{m}-") for m in self.methods)

    def run_pdf(self) -> None:
        """Build the PDF with latexmk (or pdflatex and bibtex); a LaTeX error is not fatal."""
        if shutil.which("latexmk"):
            target = "pdf"
        elif shutil.which("pdflatex") and shutil.which("bibtex"):
            target = "plain"
        else:
            self._say("pdf: neither latexmk nor pdflatex found, skipping the PDF build (the "
                      "tables and figures are written)")
            return
        if not self.default_paper:
            for name in PAPER_SOURCES:  # a self-contained paper folder under --out
                atomic_copy(REPO_ROOT / "paper" / name, self.paper / name)
        try:
            self.stage("pdf", [["make", "-C", self.paper, target]], depends=["report"],
                       outputs=[self.paper / "main.pdf"])
        except StageError as err:
            self._say(f"pdf: WARNING, the PDF was not built: {err}")

    def _keep_wall(self, stop: threading.Event) -> None:
        while not stop.wait(WALL_EVERY_S):
            self._record_wall()
            self.record_spent()
