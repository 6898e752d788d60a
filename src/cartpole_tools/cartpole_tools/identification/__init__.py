"""Plant parameter identification from recorded open-loop tests (no ROS but the node).

The thesis finds m_c, c_c,R and c_c,L by simulating the model (4.18) with
the force pulses of a test and minimising the RMSE between the simulated and
measured cart positions, summed per direction (4.22)-(4.26), and the pendulum
friction c_p, v_p from the decay of free swings (section 4.3.2, Appendix E),
then checks the whole model on the "Input" and "Oscillation" tests of
section 4.6. This module does all of it in one fit:

- every recording (:class:`Recording`: sample times, measured x and theta,
  force command held over each sample period) is replayed open loop on
  :class:`cartpole_sim.plant.Plant` (actuator (4.4), saturation, end stops,
  mechanics (4.18) with the friction (4.20)/(4.21)/(4.27)) from its own
  initial state;
- the residuals are the simulated minus measured cart position and pendulum
  angle, each recording normalised by the square root of its sample count,
  so its share of the cost is its mean square error, as (4.22) gives every
  direction's test the same say whatever its length;
- :func:`scipy.optimize.least_squares` (trust-region reflective, bounded,
  like the thesis's ``fmincon`` with bounds) varies any set of
  :class:`~cartpole_core.model.CartPoleParameters` fields, all recordings
  sharing one parameter set; optionally each recording's initial state too.

:func:`load_recording` is the thin bag loader (rosbag2/MCAP, via
``rosbags``); :func:`simulate_test` synthesises a recording of a test on
the simulated plant, to rehearse the procedure or to test this module.
:class:`PulsePlayer` plays a pulse test sample by sample with a rail guard
(the node :mod:`cartpole_tools.identification.node` puts it on ROS), and
:func:`rehearse` plays it on the simulated plant first.

Modules, one concept each:

- :mod:`.recording`: :class:`Recording`, :class:`IdentificationError`, the
  start of a recording (:func:`estimate_initial_state`, :func:`quiet_lead_in`);
- :mod:`.replay`: a recording's force commands replayed on the plant
  (:func:`simulate`, :func:`fit_initial_state`, :func:`rmse`);
- :mod:`.fit`: the least-squares fit (:func:`identify`, its result, bounds);
- :mod:`.synthetic`: recordings of tests on the simulated plant;
- :mod:`.pulse_plan`: the pulse plan (:class:`Pulse`, :func:`parse_pulse_plan`);
- :mod:`.pulse_player`: :class:`PulsePlayer`, :func:`rehearse`;
- :mod:`.bag_input`: recordings from rosbag2 bags (:func:`load_recording`);
- :mod:`.node`: the ``pulse_player`` node (rclpy).
"""
