"""The closed loop (SPEC §5–§7): plants, disturbances, reference, controllers, rollouts."""
