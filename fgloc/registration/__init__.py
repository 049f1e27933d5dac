"""Fine registration of the labelled source cloud to the labelled target cloud in SE(2)."""
