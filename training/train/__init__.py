"""DfF training: configs (JSON -> dataclasses), the loss, one loop for both nets and both simulators (DDP-ready),
checkpoints and resume, evaluation with aat_deploy.metrics."""
