"""Emotion inference on observed motion: reading a clip, its predictive density under a fitted
model, the projection onto the model's latents, and the posterior over its emotion coordinates."""
