"""mavastsm: MAVLink offboard attitude-control bridge for the ASTSM controller of Hoang & Pham (2018).

Data flows one way: MAVLink in -> vehicle state -> controller -> setpoint mapping -> safety -> MAVLink out.
See README.md for the layout.
"""

__version__ = "0.1.0"
