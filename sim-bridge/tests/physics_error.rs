//! A diverging simulation is reported like dm_control's `PhysicsError`, not stepped through.

use sim_bridge::{Environment, SimError, SuiteEnv};

#[test]
fn invalid_physics_state_is_an_error_and_ends_the_episode() {
    let mut env = SuiteEnv::new("hopper-stand", 0).unwrap();
    let mut obs = vec![0.0; env.spec().obs_dim];
    env.reset(&mut obs);
    env.try_step(&[0.0; 4], &mut obs).unwrap();
    // A velocity beyond mjMAXVAL makes MuJoCo raise mjWARN_BADQVEL (and reset its data).
    env.physics_mut().qvel_mut()[0] = 1e11;
    let err = env.try_step(&[0.0; 4], &mut obs).unwrap_err();
    assert!(matches!(err, SimError::PhysicsError { .. }), "{err}");
    assert!(err.to_string().contains("mjWARN_BADQVEL"), "{err}");
    // The episode is over until the next reset, which works again.
    assert!(matches!(
        env.try_step(&[0.0; 4], &mut obs),
        Err(SimError::EpisodeOver { .. })
    ));
    env.reset(&mut obs);
    env.try_step(&[0.0; 4], &mut obs).unwrap();
}

#[test]
fn bad_actions_are_errors_in_try_step_and_panics_in_step() {
    let mut env = SuiteEnv::new("cartpole-balance", 0).unwrap();
    let mut obs = vec![0.0; 5];
    assert!(
        matches!(
            env.try_step(&[0.0], &mut obs),
            Err(SimError::EpisodeOver { .. })
        ),
        "step before reset"
    );
    env.reset(&mut obs);
    assert!(matches!(
        env.try_step(&[0.0, 1.0], &mut obs),
        Err(SimError::ActionWidth {
            expected: 1,
            got: 2,
            ..
        })
    ));
    assert!(matches!(
        env.try_step(&[f64::NAN], &mut obs),
        Err(SimError::NonFiniteAction { index: 0, .. })
    ));
    let panic = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
        env.step(&[f64::INFINITY], &mut obs)
    }));
    assert!(panic.is_err());
}
