"""A run: its folder (:mod:`.folder`: file names, address, config, checkpoints, metrics, upgrades),
its lifecycle (:mod:`.train`: train, resume, evaluate here or on another engine), its TensorBoard
events, its video (:mod:`.render`) and the claims that keep one writer per folder
(:mod:`.folder_claims`). Everything else reads and writes runs through these modules."""
