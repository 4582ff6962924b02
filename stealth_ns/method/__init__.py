"""The nerfstudio method that ``ns-train stealth-splat(-lite)`` loads (configured in
``method_configs/``): the model and its loss, the pipeline with the attack's callbacks, the
datamanager, the trainer; their optimizers, schedules and densification; the run folder (checkpoints,
loading ``config.yml`` safely); the ``ns-export`` hook and the viewer panel (:mod:`.viewer`)."""
