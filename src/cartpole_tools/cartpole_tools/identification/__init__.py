"""Plant parameter identification from recorded open-loop tests (no ROS but the node).

The thesis finds m_c, c_c,R and c_c,L by simulating the model (4.18) with
the force pulses of a test and minimising the RMSE between the simulated and
measured cart positions, summed per direction (4.22)-(4.26), and the pendulum
friction c_p, v_p from the decay of free swings (section 4.3.2, Appendix E),
then checks the whole model on the "Input" and "Oscillation" tests of
section 4.6. This package does all of it in one fit: every recording replayed open loop on
:class:`cartpole_sim.plant.Plant`, the residuals of cart and pendulum of all
recordings minimised together by :func:`scipy.optimize.least_squares` (bounded, as
the thesis's ``fmincon``); docs/identification.md has the method and its figures.

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
