"""Resumable stages: run a command line as a named stage, stamp it when complete (with the
code it ran: commit, dirty flag, diff hash, its seconds over every invocation that worked on it
and its processes' CPU seconds in the invocation that completed it), skip it when stamped, log
it, and stop every running stage on an interrupt."""

from __future__ import annotations

import contextlib
import importlib
import os
import subprocess
import sys
import time
import traceback
from collections.abc import Sequence
from pathlib import Path

from igdrivsim import machine
from igdrivsim.errors import ConfigError, IGDrivSimError
from igdrivsim.io import atomic_write_json, read_json

REPO_ROOT = Path(__file__).resolve().parents[2]
HEARTBEAT_S = 60.0  # a stage running side by side reports its progress line this often
ONE_THREAD_FLAGS = ("--xla_cpu_multi_thread_eigen=false", "intra_op_parallelism_threads=1")


class StageError(IGDrivSimError):
    """A stage failed: the message names the stage and its log."""


class StageRunner:
    """Runs stages in ``work``; the pipeline dataclass that inherits it provides the fields."""

    def stamp_path(self, stage: str) -> Path:
        return self.work / "stages" / f"{stage}.json"

    def done(self, stage: str, depends: Sequence[str] = (),
             commands: Sequence[Sequence[str]] | None = None) -> bool:
        """Stamped (with the same ``commands``, when given), and none of ``depends`` ran again."""
        if not self.stamp_path(stage).is_file() or set(depends) & self.ran:
            return False
        return commands is None or self.stamp(stage).get("commands") == [
            list(map(str, c)) for c in commands]

    def spent_path(self, stage: str) -> Path:
        """The seconds an unfinished stage has taken so far, over its invocations."""
        return self.work / "stages" / f"{stage}.spent"

    def spent(self, stage: str) -> float:
        """Seconds of a stage over its invocations (while it runs, this one's included)."""
        if stage in self.running:
            return time.time() - self.running[stage]
        try:
            return float(read_json(self.spent_path(stage), {}).get("seconds", 0.0))
        except (TypeError, ValueError):
            return 0.0

    def record_spent(self, stages: Sequence[str] | None = None) -> None:
        """Write the seconds of ``stages`` (default: every running one): a killed run keeps them."""
        # those still running (not finished meanwhile in another lane)
        for stage in set(self.running).intersection(self.running if stages is None else stages):
            atomic_write_json(self.spent_path(stage), {"seconds": round(self.spent(stage), 1)})

    def stamp(self, stage: str) -> dict:
        """A complete stage's stamp (empty when there is none or it is unreadable)."""
        return read_json(self.stamp_path(stage), {})

    def stamped_device(self, stage: str) -> str:
        """Where a complete stage ran (this machine for a stamp without the field)."""
        return self.stamp(stage).get("device") or self.device_text

    def stamped_code(self, stage: str) -> dict:
        """The code a complete stage ran, as its stamp recorded it (unknown without the field)."""
        code = self.stamp(stage).get("code")
        return dict(code) if isinstance(code, dict) else dict(machine.UNKNOWN_CODE)

    def stamped_stages(self) -> list[str]:
        """The complete stages, in the order they finished."""
        found = [(str(self.stamp(p.stem).get("finished", "")), p.stem)
                 for p in (self.work / "stages").glob("*.json")]
        return [name for _, name in sorted(found)]

    def _say(self, text: str) -> None:
        print(f"[reproduce {time.strftime('%H:%M:%S')}] {text}", file=sys.stderr, flush=True)

    def stage(self, name: str, commands: Sequence[Sequence[str]], depends: Sequence[str] = (),
              outputs: Sequence[Path] = (), echo: bool = True) -> bool:
        """Run ``commands`` (argv lists; ``igdrivsim ...`` or ``python -m ...``) as stage
        ``name`` unless it is complete; True when it ran. ``echo=False``: the output goes to the
        log only, the terminal gets the latest progress line every minute."""
        if self.stopping.is_set():
            raise StageError(f"stage '{name}' not started: a stage beside it failed")
        if self.done(name, depends, commands) and all(Path(p).exists() for p in outputs):
            self._say(f"{name}: complete, skipped")
            return False
        log = self.work / "logs" / f"{name}.log"
        log.parent.mkdir(parents=True, exist_ok=True)
        # an old stamp must not survive a rerun that is killed: the next invocation would take
        # the half-rewritten stage (and so its dependents) for complete
        if self.stamp_path(name).is_file():  # a complete stage run again starts its count anew
            self.spent_path(name).unlink(missing_ok=True)
        self.stamp_path(name).unlink(missing_ok=True)
        self._say(f"{name}: running (log: {log})")
        start, code = time.time(), machine.code_state(REPO_ROOT)  # the code it runs
        cpu: list[float] = []  # CPU seconds of this invocation's commands (user + system)
        self.running[name] = start - self.spent(name)  # as if begun with the earlier seconds
        try:
            with open(log, "a", encoding="utf-8") as fh:
                fh.write(f"\n=== {time.strftime('%Y-%m-%d %H:%M:%S')} stage {name}\n")
                for argv in commands:
                    fh.write("$ " + " ".join(map(str, argv)) + "\n")
                    fh.flush()
                    rc = self._run(list(map(str, argv)), fh, name if not echo else None, cpu)
                    if rc != 0:
                        raise StageError(f"stage '{name}' failed (exit {rc}); read {log}")
            missing = [str(p) for p in outputs if not Path(p).exists()]
            if missing:
                raise StageError(f"stage '{name}' did not write {missing[0]}; read {log}")
            seconds = self.spent(name)
        except BaseException:
            self.record_spent([name])  # a failed or interrupted stage keeps its seconds so far
            raise
        finally:
            del self.running[name]
        atomic_write_json(self.stamp_path(name), dict(
            stage=name, seconds=round(seconds, 1), cpu_seconds=round(sum(cpu), 1),
            commands=[list(map(str, c)) for c in commands],
            finished=time.strftime("%Y-%m-%d %H:%M:%S"), device=self.device_text, code=code),
            indent=2)
        self.spent_path(name).unlink(missing_ok=True)
        self.ran.add(name)
        elapsed = time.time() - start
        self._say(f"{name}: done in {elapsed:.0f} s" + (
            f" ({seconds:.0f} s with the invocations before)" if seconds > elapsed + 1 else ""))
        return True

    def _run(self, argv: list[str], fh, beat: str | None, cpu: list[float]) -> int:
        """Run one command (``beat``: the stage whose progress line to report every minute);
        append its CPU seconds (its process and the workers it waited for) to ``cpu``."""
        if argv[0] == "igdrivsim":
            argv = ["python", "-m", "igdrivsim.cli", *argv[1:]]
        if self.in_process and argv[:2] == ["python", "-m"]:
            before = time.process_time()
            try:
                return self._run_in_process(argv[2], argv[3:], fh)
            finally:
                cpu.append(time.process_time() - before)
        if argv[0] == "python":
            argv = [sys.executable, *argv[1:]]
        env = dict(os.environ, PYTHONUNBUFFERED="1")
        # two lanes share one GPU: each takes memory as it needs it, not most of it up front;
        # the compilation cache serves later stages with the same shapes and resumed runs
        env.setdefault("XLA_PYTHON_CLIENT_PREALLOCATE", "false")
        env.setdefault("JAX_COMPILATION_CACHE_DIR", str(self.work / "jax_cache"))
        if self.one_thread:  # one worker per core: XLA's threads would only compete
            env["XLA_FLAGS"] = " ".join([env.get("XLA_FLAGS", ""), *ONE_THREAD_FLAGS]).strip()
        proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                cwd=REPO_ROOT, env=env)
        assert proc.stdout is not None
        self.children.add(proc)
        core = self._pin(proc.pid) if self.one_thread and beat is not None else None
        latest, next_beat = "", time.time() + HEARTBEAT_S
        try:
            while chunk := os.read(proc.stdout.fileno(), 4096):
                if self.stopping.is_set():
                    proc.terminate()
                text = chunk.decode("utf-8", "replace")
                fh.write(text)
                fh.flush()
                if self.quiet:
                    continue
                if beat is None:
                    print(text, end="", file=sys.stderr, flush=True)
                    continue
                lines = [ln.strip() for ln in text.replace("\r", "\n").splitlines()]
                latest = next((ln for ln in reversed(lines) if ln), latest)
                if time.time() >= next_beat and latest:
                    self._say(f"{beat}: {latest}")
                    next_beat = time.time() + HEARTBEAT_S
        except KeyboardInterrupt:
            proc.terminate()
            proc.wait()
            raise
        finally:
            self.children.discard(proc)
            if core is not None:
                with self.core_lock:
                    self.free_cores.append(core)
        try:  # wait4: this child's own CPU time, whatever runs beside it
            _, status, usage = os.wait4(proc.pid, 0)
        except ChildProcessError:  # already reaped
            return proc.wait()
        proc.returncode = os.waitstatus_to_exitcode(status)
        cpu.append(usage.ru_utime + usage.ru_stime)
        return proc.returncode

    def _pin(self, pid: int) -> int | None:
        """Give a side-by-side worker a free core of its own (None: none free or no affinity
        API): XLA runs parts of some programs on a thread pool whatever its flags, and two such
        pools on two cores slow each other. Set before the process starts its threads."""
        with self.core_lock:
            if not self.free_cores:
                return None
            core = self.free_cores.pop(0)
        try:
            os.sched_setaffinity(pid, {core})
        except OSError:  # the process already ended
            pass
        return core

    def stop(self) -> None:
        """Stop every running stage process (an interrupted run; rerunning resumes)."""
        self.stopping.set()
        for proc in list(self.children):
            proc.terminate()

    def _run_in_process(self, name: str, args: list[str], fh) -> int:
        """``python -m name args`` as the module's ``main(args)``. By name: a stage is a command
        line, and the CLI (``igdrivsim.cli``) is the layer above the pipeline."""
        out = fh if self.quiet else _Tee(fh, sys.stderr)
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(out):
            try:
                module = importlib.import_module(name)
                if not hasattr(module, "main"):  # a package: python -m runs __main__
                    module = importlib.import_module(f"{name}.__main__")
                return int(module.main(args) or 0)
            except SystemExit as err:  # argparse errors
                return int(err.code or 0) if isinstance(err.code, int) else 1
            except Exception as err:  # noqa: BLE001 - reported through the stage's log
                traceback.print_exc()
                print(f"error: {err}")
                return 1

    @contextlib.contextmanager
    def work_lock(self):
        """Hold ``WORK/pipeline.lock`` (``flock``) so that a second run on the same work folder
        is refused; the kernel drops the lock when the holder exits, even when killed."""
        import fcntl  # optional: Unix only (file locks)

        self.work.mkdir(parents=True, exist_ok=True)
        path = self.work / "pipeline.lock"
        with open(path, "a+") as fh:  # held open for the whole run
            try:
                fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                fh.seek(0)
                holder = fh.read().strip() or "another process"
                raise ConfigError(f"another reproduction is running on {self.work} (pid "
                                  f"{holder}); wait for it to finish or use another --out"
                                  ) from None
            fh.seek(0)
            fh.truncate()
            fh.write(str(os.getpid()))
            fh.flush()
            yield


class _Tee:
    """A text stream writing to a log file and to the terminal (in-process stages)."""

    def __init__(self, *streams):
        self.streams = streams

    def write(self, text: str) -> int:
        for stream in self.streams:
            stream.write(text)
        return len(text)

    def flush(self) -> None:
        for stream in self.streams:
            stream.flush()

    def isatty(self) -> bool:
        return False
