"""Shipping models: a run's translator, GDNN or policy (or a whole pipeline run) becomes the package's weights,
each with its Markdown card (:mod:`simshear_gym.ship.cards`); the ``simshear ship`` commands."""
