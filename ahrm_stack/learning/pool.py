"""Worker processes for :class:`~ahrm_stack.learning.collection.LeanCollector` (``train.env_workers`` > 1).

The ``train.num_envs`` environments are split evenly over ``train.env_workers`` processes; each
process runs a :class:`~ahrm_stack.learning.collection.LocalEnvs` of its consecutive share (each
environment a :class:`~ahrm_stack.learning.workers.WorkerEnv`: the reward mechanism's state from the
trainer, episode ends deferred to it). One step of the pool sends every worker its rows of the
actions, lets them step at once on their own cores, and gathers their arrays in environment order:
one short pipe message each way per worker per step. The step's arrays (the actions in, each
environment's values, reward, ends and reset values out) live in one block of shared memory that the
pool and its workers map (:class:`SharedStep`), each worker writing its own rows, so no array is
pickled on the way; the messages only say "step" and "done" (an action array of another shape or
dtype than the action spec's travels in the message, so that the worker's environment judges it as
in process). The batches are those of TorchRL's Collector over a ``ParallelEnv`` of the same workers
(``tests/test_collection.py`` holds them key for key); what it drops is that path's per-step machinery.

A worker that raises sends its traceback; a worker that dies (killed, out of memory) closes its
pipe. Either way the trainer gets a :class:`WorkerError` naming the worker and its environments,
and :meth:`EnvPool.close` ends the others.
"""

from __future__ import annotations

import multiprocessing
import multiprocessing.connection
import pickle
import signal
import sys
import traceback
from multiprocessing import shared_memory
from typing import Any

import numpy as np

from ahrm_stack.config import Config, MechanismConfig, SafetyConfig, TaskConfig
from ahrm_stack.env.torchrl_env import touch_penalty
from ahrm_stack.learning.collection import NUMPY_DTYPES, STEP_KEYS, LocalEnvs, StepOutput, Values

# the WorkerEnv methods the trainer calls on every environment (see workers.WorkerEnv)
CALLS = ("drain", "load_mechanism", "worker_state", "load_worker_state", "process_id", "set_near_cube_share",
         "set_touch_penalty", "set_touch_cost", "worker_settings", "mechanism_state")
CLOSE_TIMEOUT = 10.0  # s a worker gets to exit after "close" before it is terminated


class WorkerError(RuntimeError):
    """A worker process raised or died (``cause``: the worker's exception, where it could be sent)."""

    def __init__(self, message: str, cause: BaseException | None = None) -> None:
        super().__init__(message)
        self.cause = cause


def _error_reply() -> tuple[str, str, BaseException | None]:
    """("error", traceback, the exception itself where it pickles) for the exception being handled."""
    error = sys.exc_info()[1]
    try:
        pickle.dumps(error)
    except Exception:  # noqa: BLE001 - an exception that does not pickle travels as text only
        error = None
    return "error", traceback.format_exc(), error


class SharedStep:
    """One step's arrays for ``count`` environments, as views of one shared buffer (the pool's
    :class:`~multiprocessing.shared_memory.SharedMemory`, mapped by the pool and every worker):
    ``actions`` (count, action width) in; ``values`` (one array per key of ``STEP_KEYS``, a row per
    environment), ``reward``, ``terminated``, ``truncated`` and ``resets`` (the reset's values of an
    environment that ended, in its own row) out. Each array starts on a 64-byte boundary."""

    ALIGN = 64

    def __init__(self, buffer: Any, count: int, widths: dict[str, int], dtypes: dict[str, type],
                 action_width: int, action_dtype: Any) -> None:
        offset = 0

        def take(width: int | None, dtype: Any) -> np.ndarray:
            nonlocal offset
            shape = (count,) if width is None else (count, width)
            nbytes = int(np.prod(shape)) * np.dtype(dtype).itemsize
            array = (np.empty(shape, dtype=dtype) if buffer is None
                     else np.ndarray(shape, dtype=dtype, buffer=buffer, offset=offset))
            offset += -(-nbytes // self.ALIGN) * self.ALIGN
            return array

        self.actions = take(action_width, action_dtype)
        self.values = {key: take(widths[key], dtypes[key]) for key in STEP_KEYS}
        self.resets = {key: take(widths[key], dtypes[key]) for key in STEP_KEYS}
        self.reward = take(None, np.float32)
        self.terminated = take(None, np.bool_)
        self.truncated = take(None, np.bool_)
        self.nbytes = offset

    @classmethod
    def size(cls, count: int, widths: dict[str, int], dtypes: dict[str, type], action_width: int,
             action_dtype: Any) -> int:
        """Bytes of the shared buffer."""
        return cls(None, count, widths, dtypes, action_width, action_dtype).nbytes

    def write(self, start: int, output: StepOutput) -> None:
        """A worker's step (its environments are ``start``, ``start + 1``, ...) into its rows."""
        values, reward, terminated, truncated, resets = output
        stop = start + len(reward)
        for key in STEP_KEYS:
            self.values[key][start:stop] = values[key]
        self.reward[start:stop], self.terminated[start:stop], self.truncated[start:stop] = reward, terminated, truncated
        ended = np.flatnonzero(terminated | truncated) + start
        if len(ended):
            for key in STEP_KEYS:
                self.resets[key][ended] = resets[key]

    def read(self) -> StepOutput:
        """The step of every environment, copied out (the next step overwrites the buffer)."""
        terminated, truncated = self.terminated.copy(), self.truncated.copy()
        ended = np.flatnonzero(terminated | truncated)
        return ({key: value.copy() for key, value in self.values.items()}, self.reward.copy(), terminated,
                truncated, {key: value[ended] for key, value in self.resets.items()})


def _serve(conn: multiprocessing.connection.Connection, task: TaskConfig, safety: SafetyConfig,
           mechanism: MechanismConfig, seeds: tuple[int, ...], indices: tuple[int, ...], time_limit: float,
           penalty: float) -> None:
    """A worker's loop: build the environments, then answer (command, args) until "close" or until
    the trainer's end of the pipe closes. Replies are ("ok", value) or ("error", traceback,
    exception). Ctrl-C is the trainer's to handle: it closes the workers."""
    import torch

    from ahrm_stack.learning.workers import WorkerEnv

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    torch.set_num_threads(1)  # one core per worker; the environments use no torch ops per step
    try:
        envs = LocalEnvs([WorkerEnv(task, safety, mechanism, seed, index, time_limit, penalty)
                          for seed, index in zip(seeds, indices)])
        first = envs.envs[0]
        conn.send(("ok", (envs.widths, envs.dtypes, first.observation_spec, first.action_spec)))
    except Exception:  # noqa: BLE001 - reported to the trainer, which raises it
        conn.send(_error_reply())
        return
    memory: shared_memory.SharedMemory | None = None
    shared: SharedStep | None = None
    start = indices[0]
    while True:
        try:
            command, args = conn.recv()
        except (EOFError, OSError):  # the trainer is gone
            return
        try:
            if command == "close":
                shared = None  # no view of the buffer may outlive it
                if memory is not None:
                    memory.close()
                conn.send(("ok", None))
                return
            if command == "step":
                if shared is None:
                    raise RuntimeError("step before the shared buffer was attached")
                actions = args[0] if args else shared.actions[start:start + envs.count].copy()
                shared.write(start, envs.step(actions))
                reply: Any = None
            elif command == "attach":
                name, count, action_width, action_dtype = args
                memory = shared_memory.SharedMemory(name=name)
                shared = SharedStep(memory.buf, count, envs.widths, envs.dtypes, action_width, action_dtype)
                reply = None
            elif command == "begin":
                reply = envs.begin()
            elif command in CALLS:
                reply = [getattr(env, command)(*args) for env in envs.envs]
            else:
                raise ValueError(f"unknown command {command!r}")
            conn.send(("ok", reply))
        except Exception:  # noqa: BLE001 - reported to the trainer, which raises it
            conn.send(_error_reply())


def worker_arguments(config: Config, seeds: list[int]) -> list[tuple]:
    """Each worker's environments: (task, safety, mechanism, seeds, indices, time limit in s, touch
    penalty), ``len(seeds) / train.env_workers`` consecutive environments per worker."""
    workers = config.train.env_workers
    per = len(seeds) // workers
    # a delayed touch_end (train.touch_end_after) starts off; the trainer switches it on
    penalty = touch_penalty(config.train.touch_end and config.train.touch_end_after == 0, config.ppo.gamma)
    return [(config.task, config.safety, config.mechanism, tuple(seeds[w * per:(w + 1) * per]),
             tuple(range(w * per, (w + 1) * per)), config.train.time_limit, penalty) for w in range(workers)]


class EnvPool:
    """``train.env_workers`` processes stepping ``len(seeds)`` environments for
    :class:`~ahrm_stack.learning.collection.LeanCollector` (a stepper: ``count``, ``widths``,
    ``dtypes``, :meth:`begin`, :meth:`step`), with the calls the trainer makes on worker
    environments (:data:`CALLS`, methods of :class:`~ahrm_stack.learning.workers.WorkerEnv`: each
    returns one result per environment, in index order)."""

    def __init__(self, config: Config, seeds: list[int]) -> None:
        workers = config.train.env_workers
        if workers < 1 or len(seeds) % workers:
            raise ValueError(f"{len(seeds)} environments do not split over {workers} workers")
        per = len(seeds) // workers
        self.count = len(seeds)
        self.is_closed = False
        self._memory: shared_memory.SharedMemory | None = None
        self._shared: SharedStep | None = None
        self._broken = False  # a call was interrupted: replies may be left in the pipes
        self._bounds = [(w * per, (w + 1) * per) for w in range(workers)]
        context = multiprocessing.get_context("spawn")  # no fork of a process with torch's threads
        self._conns: list[multiprocessing.connection.Connection] = []
        self._processes: list[Any] = []
        try:
            for (start, stop), args in zip(self._bounds, worker_arguments(config, seeds)):
                ours, theirs = context.Pipe()
                process = context.Process(target=_serve, daemon=True, args=(theirs, *args),
                                          name=f"ahrm-env-worker-{start}-{stop - 1}")
                process.start()
                theirs.close()
                self._conns.append(ours)
                self._processes.append(process)
            layouts = self._gather()
        except WorkerError as error:
            self.close()
            if isinstance(error.cause, Exception):  # what building them in this process would raise
                raise error.cause from error
            raise
        except BaseException:
            self.close()
            raise
        self.widths, self.dtypes, self.observation_spec, self.action_spec = layouts[0]
        # the step's arrays, shared with every worker
        action_width = int(np.prod(self.action_spec.shape))
        self._action_shape = (self.count, action_width)
        self._action_dtype = np.dtype(NUMPY_DTYPES[self.action_spec.dtype])
        layout = (self.count, self.widths, self.dtypes, action_width, self._action_dtype)
        try:
            self._memory = shared_memory.SharedMemory(create=True, size=SharedStep.size(*layout))
            self._shared = SharedStep(self._memory.buf, *layout)
            attach = (self._memory.name, self.count, action_width, self._action_dtype)
            self._broadcast([("attach", attach)] * len(self._conns))
        except BaseException:
            self.close()
            raise

    def _name(self, worker: int) -> str:
        start, stop = self._bounds[worker]
        return f"environment worker {worker} (environments {start}..{stop - 1})"

    def _receive(self, worker: int) -> tuple[WorkerError | None, Any]:
        """(None, the reply) or (the error to raise, None)."""
        try:
            status, value, *cause = self._conns[worker].recv()
        except (EOFError, OSError):
            process = self._processes[worker]
            process.join(1.0)  # the pipe closes before the exit status is there to read
            return WorkerError(f"{self._name(worker)} died (exit code {process.exitcode})"), None
        if status != "ok":
            last = value.strip().splitlines()[-1] if value.strip() else "?"
            return WorkerError(f"{self._name(worker)} raised {last}\n{value}", cause[0] if cause else None), None
        return None, value

    def _gather(self) -> list[Any]:
        """Every worker's reply, in worker order (all read before the first error is raised, so that
        no reply is left in a pipe)."""
        replies = [self._receive(w) for w in range(len(self._conns))]
        for error, _ in replies:
            if error is not None:
                raise error
        return [value for _, value in replies]

    def _broadcast(self, messages: list[tuple[str, tuple]]) -> list[Any]:
        """Send worker w ``messages[w]``, then gather the replies in worker order (all are sent
        before any is awaited: the workers run at once)."""
        if self.is_closed:
            raise WorkerError("the environment pool is closed")
        if self._broken:
            raise WorkerError("the environment pool was interrupted mid-call: its pipes may hold stale replies")
        try:
            for conn, message in zip(self._conns, messages):
                try:
                    conn.send(message)
                except (BrokenPipeError, OSError):
                    pass  # the receive names the dead worker
            return self._gather()
        except WorkerError:
            raise  # every reply was read
        except BaseException:  # Ctrl-C or anything else inside a send or receive
            self._broken = True
            raise

    def begin(self) -> Values:
        parts = self._broadcast([("begin", ())] * len(self._conns))
        return {key: np.concatenate([p[key] for p in parts]) for key in STEP_KEYS}

    def step(self, actions: np.ndarray) -> StepOutput:
        """Environment i takes ``actions[i]``; the ended ones reset (see ``LocalEnvs.step``). The
        actions go through the shared buffer when they have its shape and dtype, else in the message
        (the worker's environments raise on a wrong shape as they would in process)."""
        shared = self._shared
        if shared is None:
            raise WorkerError("the environment pool is closed")
        actions = np.asarray(actions)
        if actions.shape == self._action_shape and actions.dtype == self._action_dtype:
            shared.actions[:] = actions
            self._broadcast([("step", ())] * len(self._conns))
        else:
            self._broadcast([("step", (actions[start:stop],)) for start, stop in self._bounds])
        return shared.read()

    def call(self, method: str, *args) -> list:
        """``method(*args)`` on every environment; the results in environment order."""
        if method not in CALLS:
            raise ValueError(f"unknown environment call {method!r}; one of {CALLS}")
        return [result for part in self._broadcast([(method, args)] * len(self._conns)) for result in part]

    def __getattr__(self, name: str):
        if name in CALLS:
            return lambda *args: self.call(name, *args)
        raise AttributeError(name)

    def close(self) -> None:
        """Ask every worker to exit; terminate one that does not within ``CLOSE_TIMEOUT``."""
        if self.is_closed:
            return
        self.is_closed = True
        for conn in self._conns:
            try:
                conn.send(("close", ()))
            except (BrokenPipeError, OSError):
                pass
        for conn, process in zip(self._conns, self._processes):
            process.join(CLOSE_TIMEOUT)
            if process.is_alive():
                process.terminate()
                process.join(CLOSE_TIMEOUT)
            conn.close()
        self._shared = None  # no view of the buffer may outlive it
        if self._memory is not None:
            self._memory.close()
            self._memory.unlink()
            self._memory = None


__all__ = ["CALLS", "EnvPool", "SharedStep", "WorkerError", "worker_arguments"]
