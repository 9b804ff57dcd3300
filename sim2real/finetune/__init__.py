"""Learning on the arm: a Gymnasium env over the hardware layer and keys for a human beside it."""
