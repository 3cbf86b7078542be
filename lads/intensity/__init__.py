"""The learned intensity generator: features, model, training, evaluation, prediction."""
