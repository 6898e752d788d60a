"""The Foxglove layout of the live view: ``config/foxglove_layout.json`` of this package.

A 3D panel of the rig (``/cartpole/view/scene``, looking at the rail from
the front) above the controller's mode and the events, and on the right
the four plots of the thesis's Figure 10.1, top to bottom: cart position
(estimate, ground truth, x*), pendulum angle theta_w [deg], the force
command (with the feedforward (6.12) and the plugin's own output), and the
pendulum energy E_p (7.3) with its target E*. All plots are synced and
show the last 30 s.

The file is in the layout format that both the Foxglove app and the
open-source Lichtblick import ("Import from file..." in the layout menu):
``configById`` (panel id -> settings) and a ``layout`` tree of splits.
``python -m cartpole_analysis.viewer.layout > src/cartpole_analysis/config/foxglove_layout.json``
writes it (installed as ``share/cartpole_analysis/config/foxglove_layout.json``); a test
keeps the committed file equal to :func:`foxglove_layout` and every path in it an
advertised channel's field.
"""
from __future__ import annotations

import json
import sys
from typing import Any

from cartpole_sim.geometry import RigGeometry

from .scene import FRAME
from .server import TOPICS

STATE = TOPICS['state']
CONTROL = TOPICS['control']
WINDOW_S = 30.0
"""Width of the plots' sliding time window [s]."""

PLOTS: list[tuple[str, str, list[tuple[str, str, str]]]] = [
    ('Plot!cart', 'cart position [m]', [
        (f'{STATE}.x', 'x (estimate)', '#1f77b4'),
        (f'{STATE}.x_true', 'x (truth)', '#7f7f7f'),
        (f'{STATE}.x_ref', 'x*', '#2ca02c')]),
    ('Plot!angle', 'pendulum angle theta_w [deg]', [
        (f'{STATE}.theta_w_deg', 'theta_w (estimate)', '#1f77b4'),
        (f'{STATE}.theta_w_true_deg', 'theta_w (truth)', '#7f7f7f')]),
    ('Plot!force', 'force [N]', [
        (f'{CONTROL}.force', 'force command', '#1f77b4'),
        (f'{CONTROL}.feedforward', 'feedforward (6.12)', '#ff7f0e'),
        (f'{CONTROL}.raw_force', 'controller output', '#9467bd')]),
    ('Plot!energy', 'pendulum energy [J]', [
        (f'{CONTROL}.energy', 'E_p (7.3)', '#1f77b4'),
        (f'{CONTROL}.energy_target', 'E*', '#2ca02c')]),
]
"""Panel id, title and series (path, label, colour) of the Figure 10.1 plots, top to bottom."""


def _plot(title: str, series: list[tuple[str, str, str]]) -> dict[str, Any]:
    return {
        'foxglovePanelTitle': title,
        'paths': [{'value': path, 'label': label, 'color': colour, 'enabled': True,
                   'timestampMethod': 'receiveTime'} for path, label, colour in series],
        'showXAxisLabels': True, 'showYAxisLabels': True, 'showLegend': True,
        'legendDisplay': 'floating', 'floatingLegendPosition': 'top-right',
        'showPlotValuesInLegend': False, 'isSynced': True, 'xAxisVal': 'timestamp',
        'followingViewWidth': WINDOW_S, 'sidebarDimension': 240,
    }


def _three_d(geometry: RigGeometry) -> dict[str, Any]:
    middle = 0.5 * geometry.travel
    floor = -(geometry.pendulum_length + geometry.tip_height)
    return {
        'foxglovePanelTitle': f'rig ({FRAME})',
        'cameraState': {'distance': 1.5, 'perspective': True, 'phi': 80.0, 'thetaOffset': 0.0,
                        'target': [0.0, 0.0, 0.0], 'targetOffset': [middle, 0.0, 0.0],
                        'targetOrientation': [0.0, 0.0, 0.0, 1.0], 'fovy': 45.0, 'near': 0.01,
                        'far': 50.0},
        'followMode': 'follow-none', 'followTf': FRAME,
        'scene': {'enableStats': False, 'transforms': {'showLabel': False}},
        'transforms': {},
        'topics': {TOPICS['scene']: {'visible': True}},
        'layers': {'grid': {'layerId': 'foxglove.Grid', 'instanceId': 'grid', 'label': 'Grid',
                            'visible': True, 'frameLocked': True, 'size': 2.0, 'divisions': 20,
                            'lineWidth': 1.0, 'color': '#248eff40',
                            'position': [middle, 0.0, floor], 'rotation': [0.0, 0.0, 0.0],
                            'order': 1}},
        'publish': {'type': 'point'},
    }


def _split(first, second, direction: str, percentage: float) -> dict[str, Any]:
    return {'first': first, 'second': second, 'direction': direction,
            'splitPercentage': percentage}


def foxglove_layout(geometry: RigGeometry | None = None) -> dict[str, Any]:
    """The layout (see the module docstring) as a JSON-able dict."""
    geometry = geometry or RigGeometry()
    config: dict[str, Any] = {'3D!rig': _three_d(geometry)}
    config['StateTransitions!mode'] = {
        'foxglovePanelTitle': 'controller mode',
        'paths': [{'value': f'{CONTROL}.mode', 'label': 'mode', 'timestampMethod': 'receiveTime'},
                  {'value': f'{CONTROL}.active', 'label': 'active plugin',
                   'timestampMethod': 'receiveTime'}],
        'isSynced': True}
    config['RosOut!events'] = {'foxglovePanelTitle': 'events (catch, fall, fault, switch)',
                               'searchTerms': [], 'minLogLevel': 1,
                               'topicToRender': TOPICS['events']}
    for panel, title, series in PLOTS:
        config[panel] = _plot(title, series)
    ids = [p for p, _, _ in PLOTS]
    plots = _split(ids[0], _split(ids[1], _split(ids[2], ids[3], 'column', 50.0),
                                  'column', 100.0 / 3.0), 'column', 25.0)
    left = _split('3D!rig', _split('StateTransitions!mode', 'RosOut!events', 'column', 45.0),
                  'column', 70.0)
    return {'configById': config, 'globalVariables': {}, 'userNodes': {},
            'linkedGlobalVariables': [], 'playbackConfig': {'speed': 1.0},
            'layout': _split(left, plots, 'row', 55.0)}


def layout_text() -> str:
    return json.dumps(foxglove_layout(), indent=2) + '\n'


if __name__ == '__main__':
    sys.stdout.write(layout_text())
