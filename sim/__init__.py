"""Simulated 3DR Solo that speaks MAVLink like ArduCopter 4.2+ (source folder ``sim/``).

Installed as ``mavastsm_sim`` (a wheel must not put a generic ``sim`` module in site-packages).
All imports inside this package are relative so both names work; run it with ``mavastsm sim``
or, from a source checkout, ``python -m sim``.
"""
