"""2D stage (paper section IV-B): mask -> skeleton graph -> primary and secondary 2D curves.

The entry point is :func:`recon.curve2d.fit.fit.fit_mask_curves`."""
