"""A model's forces in a fresh process (a child imports this module by path)."""


def forces_of(flags, displacement, velocity):
    from tissue_sim_ros.engine.model.material import Material, MeanRatioLaw, Viscosity
    from tissue_sim_ros.engine.mesh.generators import box_mesh
    from tissue_sim_ros.engine.model.tensor_mass import TensorMassModel
    geometric, physical, viscous = flags
    model = TensorMassModel(box_mesh((0.01, 0.01, 0.01), (3, 3, 3)), Material(5000.0, 0.45, 1000.0),
                            geometric=geometric,
                            physical=MeanRatioLaw.exponential(mu_amplitude=0.5, mu_rate=4.0) if physical else None,
                            viscosity=Viscosity(1.0, 5.0) if viscous else None)
    return model.internal_forces(displacement, velocity)
