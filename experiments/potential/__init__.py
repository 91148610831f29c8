"""The alpha-potential's pipeline: race collection, the trainings, the networks, the model cards."""
