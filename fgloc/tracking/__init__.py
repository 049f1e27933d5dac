"""GP-EOT tracking (UKF) of the vehicles a roadside radar sees, in the coarse frame C."""
