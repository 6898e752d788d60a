"""The one boundary of the `cartpole` command: every input is checked where it enters.

A refused input raises :class:`InputError` with one line that names the option
or the file and what is wrong; :func:`cartpole_bringup.cli.main` prints it as
``cartpole SUB: error: <line>`` and exits 2, like argparse, before any work
starts. Here:

- numbers: :func:`number` (finite, in range), :func:`duration`;
- files: :func:`read_yaml` (the one reader of a YAML file: missing, a
  directory, unreadable, not YAML), :func:`plant_parameters` (``--plant-params``),
  :func:`ros_parameters` (a ROS 2 parameters file, ``--params``);
- output paths: :func:`output_file` (``--plot``, ``--output``, ``--animate``)
  and :func:`output_directory` (``--plots``, ``--record``);
- JSON: :func:`json_text`, the one way a ``--json`` object is written (no NaN,
  no Infinity: a value that cannot be computed is null with a reason).
"""
from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any, Iterable

from cartpole_core.yaml_problem import yaml_problem

MAX_DURATION_S = 3600.0
"""[s] Longest run a subcommand takes: the loops keep every 5 ms sample in memory
(about 150 MB an hour offline)."""

NAME_MAX = 255
"""Longest file or directory name [bytes] (Linux's NAME_MAX)."""

DEFAULT_FIGURE_SUFFIX = '.png'
"""A figure path without an extension is written (and printed) with this one."""

EKF_NODE_PARAMETERS = ('plant_params_file', 'health_period', 'command_timeout', 'lockstep',
                       'lockstep_wait', 'use_sim_time', 'allow_duplicates')
"""The ``ekf`` node's parameters besides the filter's (:data:`ROS_PARAMETERS`)."""


class InputError(ValueError):
    """A refused input; ``str()`` is the one line to print (after ``cartpole SUB: error:``)."""


def number(option: str, value: Any, low: float | None = None, high: float | None = None, *,
           low_open: bool = False, high_open: bool = False, unit: str = '') -> float:
    """``value`` if it is a finite number in the range, else InputError naming ``option``."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise InputError(f'{option} must be a finite number, got {value!r}')
    u = f' {unit}' if unit else ''
    if low is not None and (value <= low if low_open else value < low):
        raise InputError(f'{option} must be {">" if low_open else ">="} {low:g}{u}, got {value!r}')
    if high is not None and (value >= high if high_open else value > high):
        raise InputError(f'{option} must be {"<" if high_open else "<="} {high:g}{u}, '
                         f'got {value!r}')
    return value


def duration(value: Any, option: str = '--duration') -> float:
    """A run duration [s]: finite, > 0, at most :data:`MAX_DURATION_S`."""
    return number(option, value, 0.0, MAX_DURATION_S, low_open=True, unit='s')


# -- files -----------------------------------------------------------------------------------
def input_file(path: Path | str, option: str) -> Path:
    """``path`` if it is a readable file, else InputError naming ``option`` and the path."""
    path = Path(path)
    if not path.exists():
        raise InputError(f'{option} {path}: no such file')
    if path.is_dir():
        raise InputError(f'{option} {path}: is a directory, a file is needed')
    if not os.access(path, os.R_OK):
        raise InputError(f'{option} {path}: not readable (permission denied)')
    return path


def read_yaml(path: Path | str, option: str) -> Any:
    """The YAML document in ``path``; any defect is an InputError naming the option and file."""
    import yaml

    path = input_file(path, option)
    try:
        text = path.read_text()
    except UnicodeDecodeError:
        raise InputError(f'{option} {path}: not a text file (not UTF-8)') from None
    except OSError as error:
        raise InputError(f'{option} {path}: cannot read: {error.strerror or error}') from None
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as error:
        raise InputError(f'{option} {path}: not valid YAML, {yaml_problem(error)}') from None
    except (ValueError, RecursionError) as error:  # e.g. an integer too long for YAML
        raise InputError(f'{option} {path}: not valid YAML: {error}') from None


def _keys_are_names(data: dict, option: str, path: Path, where: str) -> None:
    bad = [k for k in data if not isinstance(k, str)]
    if bad:
        raise InputError(f'{option} {path}: {where}keys must be names, got {bad[0]!r}')


def plant_parameters(path: Path | str | None, option: str = '--plant-params'):
    """The :class:`CartPoleParameters` of a plant parameters file (thesis values for None)."""
    from cartpole_core.model import CartPoleParameters

    if path is None:
        return CartPoleParameters()
    data = read_yaml(path, option)
    path = Path(path)
    if data is None:
        raise InputError(f'{option} {path}: empty; expected a mapping of plant parameters '
                         '(e.g. m_c: 4.75)')
    if isinstance(data, dict) and 'cartpole_plant' in data:
        data = data['cartpole_plant']
    if not isinstance(data, dict):
        raise InputError(f'{option} {path}: expected a mapping of plant parameters '
                         f'(e.g. m_c: 4.75), got {_kind(data)}')
    _keys_are_names(data, option, path, '')
    try:
        return CartPoleParameters.from_dict(data)
    except (ValueError, TypeError, OverflowError) as error:
        raise InputError(f'{option} {path}: {error}') from None


def ros_parameters(path: Path | str | None, node_name: str,
                   option: str = '--params') -> dict[str, Any]:
    """The ``ros__parameters`` of ``node_name`` in a ROS 2 parameters file, flattened.

    Nested mappings become dotted names (``lqg: {q: [...]}`` -> ``lqg.q``), as
    rclpy does; sections for ``/**`` apply to every node, ``/**/<node>`` (the installed
    share/<package>/config/<node>.yaml) to the node. A file that is not
    such a file (not a mapping, a node section without ``ros__parameters``, a
    key that is not a name) is an InputError.
    """
    if path is None:
        return {}
    data = read_yaml(path, option)
    path = Path(path)
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise InputError(f'{option} {path}: expected a ROS 2 parameters file (a mapping of node '
                         f'names to ros__parameters), got {_kind(data)}')
    _keys_are_names(data, option, path, '')
    out: dict[str, Any] = {}
    for key in ('/**', '/**/' + node_name, node_name, '/' + node_name):
        if key not in data:
            continue
        section = data[key]
        if not (isinstance(section, dict) and isinstance(section.get('ros__parameters'), dict)):
            raise InputError(f'{option} {path}: section {key!r} must be a mapping with a '
                             'ros__parameters mapping')
        out.update(_flatten(section['ros__parameters'], option, path, key))
    return out


def _flatten(d: dict, option: str, path: Path, section: str, prefix: str = '') -> dict[str, Any]:
    out: dict[str, Any] = {}
    _keys_are_names(d, option, path, f'{section}: ')
    for k, v in d.items():
        name = f'{prefix}{k}'
        if isinstance(v, dict):
            out.update(_flatten(v, option, path, section, name + '.'))
        else:
            out[name] = tuple(v) if isinstance(v, list) else v
    return out


def ekf_parameters(path: Path | str | None, option: str = '--params') -> dict[str, Any]:
    """The ``ekf`` section of a parameters file; an unknown name is refused with the known ones."""
    from cartpole_estimation.ekf_config import ROS_PARAMETERS

    values = ros_parameters(path, 'ekf', option)
    known = tuple(ROS_PARAMETERS) + EKF_NODE_PARAMETERS
    unknown = sorted(k for k in values if k not in known)
    if unknown:
        raise InputError(f'{option} {path}: ekf: unknown parameter(s) {", ".join(unknown)}; '
                         f'known: {", ".join(known)}')
    return values


def _kind(data: Any) -> str:
    return {list: 'a list', str: 'a string', int: 'a number', float: 'a number',
            bool: 'a boolean'}.get(type(data), type(data).__name__)


# -- output paths ------------------------------------------------------------------------------
def _writable_parent(path: Path, option: str, shown: Path) -> None:
    parent = path.parent if str(path.parent) else Path('.')
    if not parent.exists():
        raise InputError(f'{option} {shown}: the directory {parent} does not exist')
    if not parent.is_dir():
        raise InputError(f'{option} {shown}: {parent} is not a directory')
    if not os.access(parent, os.W_OK | os.X_OK):
        raise InputError(f'{option} {shown}: cannot write into {parent} (permission denied)')


def figure_formats() -> tuple[str, ...]:
    """The file extensions matplotlib writes (``png``, ``pdf``, ``svg``, ...)."""
    from matplotlib.backend_bases import FigureCanvasBase
    return tuple(sorted(FigureCanvasBase.get_supported_filetypes()))


def output_file(path: Path | str, option: str, suffixes: Iterable[str] | None = None,
                default_suffix: str | None = None) -> Path:
    """The path to write, checked before any work: not a directory, its directory exists
    and is writable, its extension one of ``suffixes`` (with the dot; None: any).

    Without an extension, ``default_suffix`` is added (the path returned is the
    one written, so the one to print); without a default it is refused.
    """
    shown = Path(path)
    path = Path(path)
    allowed = tuple(s.lower() for s in suffixes) if suffixes is not None else None
    if not path.suffix:
        if default_suffix is None:
            raise InputError(f'{option} {shown}: needs an extension'
                             + (f' ({", ".join(allowed)})' if allowed else ''))
        path = path.with_name(path.name + default_suffix)
    if allowed is not None and path.suffix.lower() not in allowed:
        raise InputError(f'{option} {shown}: must be one of {", ".join(allowed)} (cannot '
                         f'write {path.suffix!r} files)')
    _short_names(path, option)
    if path.is_dir():
        raise InputError(f'{option} {path}: is a directory, a file name is needed')
    if path.exists() and not os.access(path, os.W_OK):
        raise InputError(f'{option} {path}: cannot overwrite (permission denied)')
    _writable_parent(path, option, shown)
    return path


def figure_file(path: Path | str, option: str) -> Path:
    """:func:`output_file` for a matplotlib figure; no extension means ``.png``."""
    return output_file(path, option, tuple('.' + s for s in figure_formats()),
                       DEFAULT_FIGURE_SUFFIX)


def _short_names(path: Path, option: str) -> None:
    """Refuse a path with a name longer than the file system takes (:data:`NAME_MAX`)."""
    longest = max((len(part.encode()) for part in path.parts), default=0)
    if longest > NAME_MAX:
        raise InputError(f'{option} {str(path)[:60]}...: a name in it is {longest} bytes long, '
                         f'the file system takes at most {NAME_MAX}')


def output_directory(path: Path | str, option: str) -> Path:
    """A directory to write into (made if missing): refused when the path or one of its
    parents is a file, or it cannot be written."""
    path = Path(path)
    _short_names(path, option)
    probe = path
    while not probe.exists():
        if probe.parent == probe:
            break
        probe = probe.parent
    if not probe.is_dir():
        what = 'exists and is not a directory' if probe == path else f'{probe} is a file'
        raise InputError(f'{option} {path}: {what}, a directory is needed')
    if not os.access(probe, os.W_OK | os.X_OK):
        raise InputError(f'{option} {path}: cannot write into {probe} (permission denied)')
    return path


# -- JSON --------------------------------------------------------------------------------------
def json_safe(value: Any, reasons: dict[str, str] | None = None, where: str = '') -> Any:
    """``value`` with every NaN or infinite float replaced by None; ``reasons`` collects
    ``{'key.path': 'NaN: ...'}`` for each."""
    if isinstance(value, float) and not math.isfinite(value):
        if reasons is not None:
            reasons[where or 'value'] = ('not computable (NaN)' if math.isnan(value)
                                         else f'not finite ({value})')
        return None
    if isinstance(value, dict):
        return {k: json_safe(v, reasons, f'{where}.{k}' if where else str(k))
                for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_safe(v, reasons, f'{where}[{i}]') for i, v in enumerate(value)]
    if hasattr(value, 'item') and callable(value.item) and not isinstance(value, (str, bytes)):
        try:  # numpy scalars
            return json_safe(value.item(), reasons, where)
        except (TypeError, ValueError):
            return value
    return value


def json_text(obj: Any, **kwargs) -> str:
    """``obj`` as strict JSON: a NaN or Infinity becomes null, and a mapping gets
    ``null_reasons`` ({key: why}) for each such value."""
    reasons: dict[str, str] = {}
    safe = json_safe(obj, reasons)
    if reasons and isinstance(safe, dict):
        safe['null_reasons'] = {**safe.get('null_reasons', {}), **reasons} \
            if isinstance(safe.get('null_reasons'), dict) else reasons
    return json.dumps(safe, allow_nan=False, **kwargs)
