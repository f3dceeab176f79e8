"""Validation on simulated truth: the layer above the analyses and the simulator.

Helpers that drive simulator scenarios and judge the analyses against the hidden truth
(:mod:`~cnctwin.validation.trials`: faults at hidden times; :mod:`~cnctwin.validation.wearcheck`:
the wear run read chunk by chunk) and the demo report's sections
(:mod:`~cnctwin.validation.servo_section`, :mod:`~cnctwin.validation.usecases_section`) with
their :class:`~cnctwin.validation.context.DemoContext`. Nothing below this layer imports it.
"""
