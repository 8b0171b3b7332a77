"""The official Kilobotics labs (SSR-Harvard/kilobotics-labs), ported line by line to kilonet.

One module per lab, each with the lab's program as a module-level Kilobot subclass (for
``kilonet run --program``) and a one-command run (``python -m examples.labs.LAB``); ``world``
loads each lab's placement and parameters, ``measures`` measures what the lab does. See
``README.md`` beside this file for the figures and the commands behind them.
"""
