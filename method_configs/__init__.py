"""Method definitions registered with nerfstudio (installed as ``stealth_ns.method_configs``)."""
