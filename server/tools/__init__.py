"""Command-line tools on top of the arena: ``neuronsmae-match``, ``neuronsmae-demo``,
``neuronsmae-replay`` and the video writer they share."""
