"""Packaged configuration files (YAML). Installed as ``mavastsm.configs``; see config_loading."""
