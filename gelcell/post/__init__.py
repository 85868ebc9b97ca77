"""After a solve: the fields of a device, the quantities users read, the interface checks, the model's limits.

``fields`` (the solution on the region meshes, from either method) →
``quantities`` (model.md section 7) and ``residuals`` (the interface
conditions); ``validity`` says what the model can answer, before a solve
(limits) and after it (warnings).
"""
