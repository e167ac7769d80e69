"""Command-line tools on top of the arena: ``neuronsmae-demo``, ``neuronsmae-replay`` and
the video writer they share (``neuronsmae-match`` and ``neuronsmae-league``, which pit
policies against each other, live with the trainers: trainers/play/match.py)."""
