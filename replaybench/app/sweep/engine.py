"""Ray for a sweep: a local instance or a cluster joined as it is, and where cells may run.

Placement (measurement validity first):

* a timed CPU cell gets a node to itself. Where an operator declared the custom resource
  ``replaybench_timed_slot`` on some nodes (one unit each), a cell holds one unit: those nodes,
  one cell at a time. On any other cluster (no custom resources: KubeRay, ``ray up``, a plain
  ``ray start --head``) a cell holds every CPU of one node, pinned there with hard node
  affinity (``NodeAffinitySchedulingStrategy``); the driver hands each node one cell at a time;
* a GPU cell (its backend declares ``device = 'cuda'``) holds one GPU: a node runs as many GPU
  cells as it has GPUs, one per GPU;
* ``pack`` drops the node rule: CPU cells fill every core (accuracy-only sweeps).

``ray.init`` installs signal handlers and sets environment variables, and token authentication
is read from the environment: ``engine`` puts the process back as it found it afterwards.
"""

from __future__ import annotations

import contextlib
import logging
import os
import secrets
import signal
import sys
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from replaybench.errors import EngineError, UsageError

if TYPE_CHECKING:
    from collections.abc import Iterator, Mapping

    from replaybench.app.sweep.plan import Cell
    from replaybench.results.sweepfile import SweepEngine

__all__ = [
    'LOCAL_NODE_IP',
    'NODE_SLOT',
    'Placement',
    'engine',
    'engine_record',
    'error_line',
    'import_ray',
    'join_auth_env',
    'local_ray',
]

#: The custom Ray resource a timed CPU cell holds where nodes declare it (one unit per node).
NODE_SLOT = 'replaybench_timed_slot'
#: Address the local Ray instance listens on: loopback only (Ray maps 127.0.0.1 itself to the
#: machine's network address, so another loopback address is used on Linux).
LOCAL_NODE_IP = '127.0.0.2' if sys.platform.startswith('linux') else None

_AUTH_MODE = 'RAY_AUTH_MODE'
_AUTH_TOKEN = 'RAY_AUTH_TOKEN'
_AUTH_TOKEN_PATH = 'RAY_AUTH_TOKEN_PATH'
_PROCESS_TOKEN: list[str] = []


def error_line(err: BaseException) -> str:
    """The first line of an error: its message, or its type and message when it is not one of
    replaybench's own."""
    from replaybench.errors import ReplaybenchError

    text = str(err) if isinstance(err, ReplaybenchError) else f'{type(err).__name__}: {err}'
    lines = [line.strip() for line in text.splitlines() if line.strip()]
    return lines[0] if lines else type(err).__name__


def _token_available(environ: Mapping[str, str], home: Path) -> bool:
    if environ.get(_AUTH_TOKEN):
        return True
    path = environ.get(_AUTH_TOKEN_PATH)
    if path:
        return Path(path).is_file()
    return (home / '.ray' / 'auth_token').is_file()


def join_auth_env(
    address: str | None, environ: Mapping[str, str], home: Path | None = None
) -> dict[str, str]:
    """The variables to set for Ray's token authentication (Ray >= 2.60) before ``ray.init``.

    An explicit ``RAY_AUTH_MODE`` is always kept. Local instance (``address`` None): token
    authentication with ``RAY_AUTH_TOKEN`` (the given one, else a token of this process), so
    nothing is written to ``~/.ray``. Joining a cluster: token mode when a token is at hand
    (``RAY_AUTH_TOKEN``, ``RAY_AUTH_TOKEN_PATH`` or ``~/.ray/auth_token``), which joins
    clusters with and without authentication alike; else nothing (a cluster started without
    authentication).
    """
    if _AUTH_MODE in environ:
        return {}
    if address is None:
        if not _PROCESS_TOKEN:
            _PROCESS_TOKEN.append(secrets.token_hex(32))
        return {_AUTH_MODE: 'token', _AUTH_TOKEN: environ.get(_AUTH_TOKEN) or _PROCESS_TOKEN[0]}
    if _token_available(environ, home if home is not None else Path.home()):
        return {_AUTH_MODE: 'token'}
    return {}


@contextlib.contextmanager
def _environment(changes: Mapping[str, str]) -> Iterator[None]:
    """``os.environ`` with ``changes`` (Ray's cached auth settings refreshed), restored after."""
    before = {k: os.environ.get(k) for k in changes}
    os.environ.update(changes)
    _refresh_ray_auth(bool(changes))
    try:
        yield
    finally:
        for k, v in before.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
        _refresh_ray_auth(bool(changes))


def _refresh_ray_auth(changed: bool) -> None:
    """Ray reads RAY_AUTH_MODE and the token once per process; read them again."""
    if not changed:
        return
    import importlib

    raylet = importlib.import_module('ray._raylet')
    config = getattr(raylet, 'Config', None)
    loader = getattr(raylet, 'AuthenticationTokenLoader', None)
    if config is None or loader is None:  # a Ray without token authentication
        return
    config.initialize('')
    loader.instance().reset_cache()


def import_ray() -> Any:
    """The ``ray`` module; UsageError naming the extra when it is not installed."""
    try:
        with _as_found():  # importing Ray sets RAY_CLIENT_MODE
            import ray
    except ImportError as err:
        msg = "replaybench sweep needs Ray: pip install 'replaybench[sweep]'"
        raise UsageError(msg) from err
    return ray


@contextlib.contextmanager
def local_ray(
    *, num_cpus: int | None = None, temp_dir: str | None = None
) -> Iterator[dict[str, Any]]:
    """A local Ray instance for a sweep: one node slot, no dashboard, quiet logs, loopback only,
    token authentication with a token of this process; shut down on exit."""
    ray = import_ray()
    with _environment(join_auth_env(None, os.environ)):
        try:
            context = ray.init(
                address='local',  # a new instance, never a cluster `ray start` left running
                num_cpus=num_cpus,
                resources={NODE_SLOT: 1},
                include_dashboard=False,
                logging_level=logging.ERROR,
                log_to_driver=False,
                _node_ip_address=LOCAL_NODE_IP,
                _temp_dir=temp_dir,
            )
        except Exception as err:  # Ray's start-up fails in many types: one line
            msg = f'cannot start a local Ray instance: {error_line(err)}'
            raise EngineError(msg) from err
        try:
            yield {'mode': 'local', 'address': context.address_info.get('gcs_address')}
        finally:
            ray.shutdown()


@contextlib.contextmanager
def _joined_ray(address: str) -> Iterator[dict[str, Any]]:
    ray = import_ray()
    changes = join_auth_env(address, os.environ)
    with _environment(changes):
        try:
            ray.init(address=address, logging_level=logging.ERROR, log_to_driver=False)
        except Exception as err:  # Ray's connection fails in many types: one line
            hint = (
                ''
                if os.environ.get(_AUTH_MODE) == 'token'
                else '; a cluster with token authentication needs its token here: set '
                "RAY_AUTH_TOKEN (or copy the head's ~/.ray/auth_token) or RAY_AUTH_MODE "
                '(docs/sweep.md)'
            )
            msg = f'cannot join the Ray cluster at {address}: {error_line(err)}{hint}'
            raise EngineError(msg) from err
        try:
            yield {'mode': 'cluster', 'address': address}
        finally:
            ray.shutdown()


@contextlib.contextmanager
def _as_found() -> Iterator[None]:
    """``ray.init`` installs a SIGTERM handler and sets environment variables in this process:
    a sweep that started or joined Ray puts the handlers and ``os.environ`` back as it found
    them once Ray has shut down."""
    environ = dict(os.environ)
    handlers: dict[signal.Signals, Any] = {}
    if threading.current_thread() is threading.main_thread():
        handlers = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        for sig, handler in handlers.items():
            if handler is not None:
                signal.signal(sig, handler)
        for key in set(os.environ) - set(environ):
            del os.environ[key]
        for key, value in environ.items():
            if os.environ.get(key) != value:
                os.environ[key] = value


@contextlib.contextmanager
def engine(address: str | None) -> Iterator[dict[str, Any]]:
    """Ray for the sweep: the connection already made in this process, else the cluster at
    ``address``, else a local instance started (and shut down) here."""
    ray = import_ray()
    if ray.is_initialized():
        yield {'mode': 'connected', 'address': ray.get_runtime_context().gcs_address}
    elif address is not None:
        with _as_found(), _joined_ray(address) as info:
            yield info
    else:
        with _as_found(), local_ray() as info:
            yield info


@dataclass(frozen=True, slots=True)
class Placement:
    """Where the cells may run: ``slot`` (nodes declare ``NODE_SLOT``), ``whole-node`` (every
    CPU of one node, ``nodes`` by id with their CPU count) or ``packed``."""

    mode: str  # 'slot' | 'whole-node' | 'packed'
    nodes: tuple[tuple[str, float], ...] = ()

    @classmethod
    def of(cls, nodes: Mapping[str, Mapping[str, float]], pack: bool) -> Placement:
        """The placement on a cluster of ``nodes`` (alive ones, by id, with their resources)."""
        if pack:
            return cls('packed')
        if any(r.get(NODE_SLOT, 0) > 0 for r in nodes.values()):
            return cls('slot')
        usable = tuple(
            (node_id, float(r['CPU']))
            for node_id, r in sorted(nodes.items())
            if r.get('CPU', 0) >= 1
        )
        return cls('whole-node', usable)

    @property
    def describe(self) -> str:
        """sweep.json's ``engine.placement.cpu_cells``."""
        if self.mode == 'packed':
            return 'packed, one per CPU'
        if self.mode == 'slot':
            return f'one timed cell per node ({NODE_SLOT})'
        return "one timed cell per node (all the node's CPUs, node affinity)"

    def options(self, cell: Cell, node: tuple[str, float] | None = None) -> dict[str, Any]:
        """``remote.options`` of ``cell``; ``node`` (id, CPUs) for a whole-node cell."""
        options: dict[str, Any] = {'num_cpus': 1, 'name': f'replaybench cell {cell.name}'}
        if cell.gpu:
            options['num_gpus'] = 1
        elif self.mode == 'slot':
            options['resources'] = {NODE_SLOT: 1}
        elif self.mode == 'whole-node':
            assert node is not None
            from ray.util.scheduling_strategies import NodeAffinitySchedulingStrategy

            options['num_cpus'] = node[1]
            options['scheduling_strategy'] = NodeAffinitySchedulingStrategy(node[0], soft=False)
        return options

    def one_node_each(self, cell: Cell) -> bool:
        """Whether the driver hands ``cell`` to a node of its own (whole-node CPU cells)."""
        return self.mode == 'whole-node' and not cell.gpu


def alive_nodes(ray: Any) -> dict[str, dict[str, float]]:
    """The alive nodes of the cluster by id, with their resources (``node:`` ones left out)."""
    return {
        str(n['NodeID']): {
            k: float(v) for k, v in n.get('Resources', {}).items() if not k.startswith('node:')
        }
        for n in ray.nodes()
        if n.get('Alive')
    }


def engine_record(ray: Any, info: Mapping[str, Any], placement: Placement) -> SweepEngine:
    """sweep.json's ``engine``: Ray, the nodes, their resources and the placement rules."""
    from replaybench.results.sweepfile import EngineNode, EnginePlacement, SweepEngine

    nodes = []
    head = None
    for node in sorted(ray.nodes(), key=lambda n: str(n.get('NodeID'))):
        resources = {
            k: float(v) for k, v in node.get('Resources', {}).items() if not k.startswith('node:')
        }
        if 'node:__internal_head__' in node.get('Resources', {}):
            head = node.get('NodeID')
        nodes.append(
            EngineNode(
                node_id=str(node.get('NodeID')),
                ip=node.get('NodeManagerAddress'),
                hostname=node.get('NodeManagerHostname'),
                alive=bool(node.get('Alive')),
                resources=resources,
            )
        )
    resources = {
        k: float(v) for k, v in ray.cluster_resources().items() if not k.startswith('node:')
    }
    return SweepEngine(
        ray_version=ray.__version__,
        mode=info['mode'],
        address=info.get('address'),
        head_node_id=head,
        resources=dict(sorted(resources.items())),
        nodes=tuple(nodes),
        placement=EnginePlacement(
            node_slot=NODE_SLOT, cpu_cells=placement.describe, gpu_cells='one per GPU'
        ),
        auth_mode=os.environ.get(_AUTH_MODE, 'disabled'),
    )
