"""The README's parameter, plugin and topic tables, generated from the code.

``python -m cartpole_tools.readme_tables --write`` rewrites every region of
README.md between ``<!-- generated: KIND NAME -->`` and ``<!-- end generated -->``;
``--check`` exits 1 naming each region that disagrees with the code. The facts
come from the nodes themselves (built in-process, their declared parameters
and descriptors, publishers, subscriptions and services), the controller
plugin registry and the recorder's topic list (:data:`cartpole_analysis.bags.writer.TOPICS`).
"""
