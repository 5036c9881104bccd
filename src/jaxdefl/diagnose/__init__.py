"""Missing-physics diagnosis: where a recording departs from the nominal model, which physics
was left out, its model and how much the fit improves (``jaxdefl diagnose``)."""
