"""Plant parameter identification from recorded open-loop tests (no ROS but the node).

The thesis finds m_c, c_c,R and c_c,L by simulating the model (4.18) with the force pulses
of a test and minimising the RMSE of the cart position per direction (4.22)-(4.26), the
pendulum friction c_p, v_p from the decay of free swings (section 4.3.2, Appendix E), and
checks the whole model on the "Input" and "Oscillation" tests of section 4.6. This package
does all of it in one fit: every recording replayed open loop on
:class:`cartpole_sim.plant.Plant`, the residuals of cart and pendulum of all recordings
minimised together by :func:`scipy.optimize.least_squares` (bounded, as ``fmincon``).
The method and its figures: (docs/identification.md, "Identifying the plant parameters").

Modules: :mod:`.recording` (:class:`Recording`, the start of a recording); :mod:`.replay`
(a recording's forces replayed on the plant, :func:`rmse`); :mod:`.fit` (:func:`identify`,
its result, bounds); :mod:`.synthetic` (recordings of tests on the simulated plant);
:mod:`.pulse_plan` (:class:`Pulse`, :func:`parse_pulse_plan`); :mod:`.pulse_player`
(:class:`PulsePlayer`, :func:`rehearse`); :mod:`.bag_input` (:func:`load_recording`);
:mod:`.node` (the ``pulse_player`` node, rclpy).
"""
