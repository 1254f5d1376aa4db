"""Learning on the stream: the online combination of the predictors (:mod:`.combination`)."""
