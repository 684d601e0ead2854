# End-to-end check of the command-line tools: synthesize a take, inspect it, calibrate
# a subject from it. Run by CTest with MOCAP_SIM, MOCAPD and WORK_DIR defined.
file(REMOVE_RECURSE ${WORK_DIR})
file(MAKE_DIRECTORY ${WORK_DIR})

function(run)
  execute_process(COMMAND ${ARGN} RESULT_VARIABLE rc OUTPUT_VARIABLE out ERROR_VARIABLE err)
  if(NOT rc EQUAL 0)
    message(FATAL_ERROR "command failed (${rc}): ${ARGN}\n${out}\n${err}")
  endif()
  set(OUT "${out}" PARENT_SCOPE)
endfunction()

run(${MOCAP_SIM} synth --humanoid walk --seconds 4 --rate 120 --out ${WORK_DIR}/walk.c3d
    --subject-out ${WORK_DIR}/synthetic.toml --truth-bvh ${WORK_DIR}/walk.bvh)
run(${MOCAP_SIM} info ${WORK_DIR}/walk.c3d --json)
string(JSON frames GET "${OUT}" frames)
string(JSON rate GET "${OUT}" rate_hz)
string(JSON first_label GET "${OUT}" points 0 label)
if(NOT frames EQUAL 480 OR NOT rate EQUAL 120 OR NOT first_label STREQUAL "PEL1")
  message(FATAL_ERROR "info --json reported frames=${frames} rate=${rate} first label=${first_label}")
endif()
run(${MOCAP_SIM} info ${WORK_DIR}/walk.bvh)
if(NOT OUT MATCHES "Hips \\(free\\)")
  message(FATAL_ERROR "info on the BVH did not list the free root:\n${OUT}")
endif()
run(${MOCAPD} calibrate --skeleton ${WORK_DIR}/walk.bvh --markers ${WORK_DIR}/walk.c3d --out ${WORK_DIR}/calibrated.toml)
if(NOT OUT MATCHES "markers accepted, 0 rejected")
  message(FATAL_ERROR "calibrate did not accept every marker:\n${OUT}")
endif()
# From markers alone: a Plug-in Gait range of motion with soft tissue, calibrated with no
# skeleton given (the set recognised from the labels), then a corrupted take of the same
# body cleaned with that subject; the subject keeps the role names in its BVH.
run(${MOCAP_SIM} synth --humanoid rom --seconds 10 --rate 120 --marker-set plug-in-gait-full --noise-mm 1
    --soft-tissue-mm 5 --out ${WORK_DIR}/rom.c3d)
run(${MOCAPD} calibrate --markers ${WORK_DIR}/rom.c3d --out ${WORK_DIR}/markers_only.toml
    --report ${WORK_DIR}/calibration.json)
if(NOT OUT MATCHES "marker set plug-in-gait-full \\(40 markers\\)")
  message(FATAL_ERROR "calibrate --markers did not recognise the set:\n${OUT}")
endif()
file(READ ${WORK_DIR}/calibration.json calibration)
string(JSON joint0 GET "${calibration}" joints 0 joint)
string(JSON residual GET "${calibration}" median_residual_mm)
if(NOT joint0 STREQUAL "pelvis" OR residual GREATER 5)
  message(FATAL_ERROR "calibration report: first joint ${joint0}, median residual ${residual} mm")
endif()
run(${MOCAP_SIM} synth --humanoid mixed --seconds 3 --rate 120 --marker-set plug-in-gait-full --out
    ${WORK_DIR}/pig_bad.c3d --corrupt medium --seed 3)
run(${MOCAPD} process --subject ${WORK_DIR}/markers_only.toml --in ${WORK_DIR}/pig_bad.c3d --out-bvh
    ${WORK_DIR}/pig_solved.bvh)
run(${MOCAP_SIM} info ${WORK_DIR}/pig_solved.bvh)
if(NOT OUT MATCHES "thigh_l \\(ball\\)" OR NOT OUT MATCHES "pelvis \\(free\\)")
  message(FATAL_ERROR "the solved BVH does not keep the role names:\n${OUT}")
endif()
# A take too short to calibrate from: a clear error, nothing written (a take with no
# motion is the unit tests' case).
run(${MOCAP_SIM} synth --humanoid walk --seconds 0.1 --rate 60 --marker-set cmu-41 --out ${WORK_DIR}/still.c3d)
execute_process(COMMAND ${MOCAPD} calibrate --markers ${WORK_DIR}/still.c3d --out ${WORK_DIR}/still.toml
                RESULT_VARIABLE rc ERROR_VARIABLE err)
if(NOT rc EQUAL 1 OR EXISTS ${WORK_DIR}/still.toml OR NOT err MATCHES "mocapd: error: calibrate: ")
  message(FATAL_ERROR "calibrating a still take: rc=${rc} err=${err}")
endif()

# A corrupted take, cleaned through the streaming pipeline.
run(${MOCAP_SIM} synth --humanoid mixed --seconds 5 --rate 120 --out ${WORK_DIR}/bad.c3d --corrupt medium --seed 2
    --truth ${WORK_DIR}/truth.json)
if(NOT OUT MATCHES "corrupted 1[5-9]")
  message(FATAL_ERROR "synth --corrupt medium did not corrupt ~15 % of samples:\n${OUT}")
endif()
file(READ ${WORK_DIR}/truth.json truth)
string(JSON severity GET "${truth}" severity)
if(NOT severity STREQUAL "medium")
  message(FATAL_ERROR "truth mask names severity ${severity}")
endif()
run(${MOCAPD} process --subject ${WORK_DIR}/synthetic.toml --in ${WORK_DIR}/bad.c3d --out-bvh ${WORK_DIR}/solved.bvh
    --out-c3d ${WORK_DIR}/cleaned.c3d --lookahead 4 --report ${WORK_DIR}/report.json)
file(READ ${WORK_DIR}/report.json report)
string(JSON frames_in GET "${report}" frames_in)
string(JSON frames_out GET "${report}" frames_out)
if(NOT frames_in EQUAL 600 OR NOT frames_out EQUAL 600)
  message(FATAL_ERROR "process: frames in ${frames_in}, out ${frames_out}")
endif()
run(${MOCAP_SIM} info ${WORK_DIR}/solved.bvh --json)
string(JSON solved_frames GET "${OUT}" frames)
if(NOT solved_frames EQUAL 600)
  message(FATAL_ERROR "the solved BVH has ${solved_frames} frames, expected 600")
endif()
# Retargeting onto a character: a 1.2x humanoid written as BVH by synth, its rest pose
# and hierarchy taken from the file; the character's motion lines up frame for frame.
run(${MOCAP_SIM} synth --humanoid walk --seconds 1 --out ${WORK_DIR}/char_markers.c3d --truth-bvh ${WORK_DIR}/character.bvh)
run(${MOCAPD} process --subject ${WORK_DIR}/synthetic.toml --in ${WORK_DIR}/bad.c3d --out-bvh ${WORK_DIR}/solved2.bvh
    --retarget ${WORK_DIR}/character.bvh --out-character-bvh ${WORK_DIR}/character_out.bvh --joint-map head=Head)
if(NOT OUT MATCHES "retarget map: 21 bones matched" OR NOT OUT MATCHES "hand_l: LeftHand -> LeftHand")
  message(FATAL_ERROR "process --retarget did not report the joint map:\n${OUT}")
endif()
run(${MOCAP_SIM} info ${WORK_DIR}/character_out.bvh --json)
string(JSON character_frames GET "${OUT}" frames)
if(NOT character_frames EQUAL 600)
  message(FATAL_ERROR "the character BVH has ${character_frames} frames, expected 600")
endif()
execute_process(COMMAND ${MOCAPD} process --subject ${WORK_DIR}/synthetic.toml --in ${WORK_DIR}/bad.c3d --out-bvh ${WORK_DIR}/x.bvh
                        --retarget ${WORK_DIR}/character.bvh --joint-map hand_l=NoSuchJoint RESULT_VARIABLE rc ERROR_VARIABLE err)
if(NOT rc EQUAL 1 OR NOT err MATCHES "no joint 'NoSuchJoint'")
  message(FATAL_ERROR "a bad joint map: rc=${rc} err=${err}")
endif()
# Bad input gets a clear error and a non-zero exit, not a crash.
file(WRITE ${WORK_DIR}/broken.c3d "not a c3d file")
execute_process(COMMAND ${MOCAP_SIM} info ${WORK_DIR}/broken.c3d RESULT_VARIABLE rc ERROR_VARIABLE err)
if(NOT rc EQUAL 1 OR NOT err MATCHES "header section")
  message(FATAL_ERROR "broken C3D: rc=${rc} err=${err}")
endif()
# A BVH that is no humanoid (an arm) is named by synth and replay (they said only "not a
# recognisable humanoid").
file(WRITE ${WORK_DIR}/arm.bvh "HIERARCHY\nROOT Base\n{\n  OFFSET 0 0 0\n  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation\n  JOINT Link1\n  {\n    OFFSET 0 30 0\n    CHANNELS 3 Zrotation Xrotation Yrotation\n    End Site\n    {\n      OFFSET 0 30 0\n    }\n  }\n}\nMOTION\nFrames: 2\nFrame Time: 0.0333333\n0 0 0 0 0 0 0 0 0\n0 0 0 0 0 0 10 0 0\n")
foreach(command synth replay)
  if(command STREQUAL synth)
    set(args synth --bvh ${WORK_DIR}/arm.bvh --out ${WORK_DIR}/arm.c3d)
  else()
    set(args replay ${WORK_DIR}/arm.bvh --connect-timeout 1 --to tcp://127.0.0.1:1)
  endif()
  execute_process(COMMAND ${MOCAP_SIM} ${args} RESULT_VARIABLE rc ERROR_VARIABLE err)
  if(NOT rc EQUAL 1 OR NOT err MATCHES "arm.bvh: not a recognisable humanoid")
    message(FATAL_ERROR "${command} of a BVH that is no humanoid: rc=${rc} err=${err}")
  endif()
endforeach()
# An output naming an input is refused before anything is written: the input survives.
file(SHA256 ${WORK_DIR}/walk.bvh walk_before)
execute_process(COMMAND ${MOCAP_SIM} synth --bvh ${WORK_DIR}/walk.bvh --out ${WORK_DIR}/./walk.bvh
                RESULT_VARIABLE rc ERROR_VARIABLE err)
file(SHA256 ${WORK_DIR}/walk.bvh walk_after)
if(NOT rc EQUAL 1 OR NOT err MATCHES "is the same file as --bvh" OR NOT walk_before STREQUAL walk_after)
  message(FATAL_ERROR "synth over its own BVH: rc=${rc} err=${err}")
endif()
# A replay whose labels are mostly not the subject's (a Plug-in Gait take against the
# built-in humanoid) says so before it sends; with no daemon it then fails to connect.
execute_process(COMMAND ${MOCAP_SIM} replay ${WORK_DIR}/rom.c3d --connect-timeout 1 --to tcp://127.0.0.1:1
                RESULT_VARIABLE rc OUTPUT_VARIABLE out ERROR_VARIABLE err)
if(NOT out MATCHES "warning: only [0-9]+ of the subject's 59 markers \\(the built-in humanoid\\)")
  message(FATAL_ERROR "replay of another set's take gave no warning: rc=${rc}\n${out}\n${err}")
endif()
# A motion graph's source takes are inputs of graph synth / match too.
run(${MOCAP_SIM} graph build ${WORK_DIR}/walk.bvh --out ${WORK_DIR}/walk_graph.json)
execute_process(COMMAND ${MOCAP_SIM} graph synth --graph ${WORK_DIR}/walk_graph.json --distance 1 --time 2
                        --out ${WORK_DIR}/walk.bvh RESULT_VARIABLE rc ERROR_VARIABLE err)
file(SHA256 ${WORK_DIR}/walk.bvh walk_after_graph)
if(NOT rc EQUAL 1 OR NOT err MATCHES "'s take" OR NOT walk_before STREQUAL walk_after_graph)
  message(FATAL_ERROR "graph synth over its own take: rc=${rc} err=${err}")
endif()
# A value that is not a number names itself ("Value abc not in range 0 to 1000" read as
# a number out of range).
execute_process(COMMAND ${MOCAPD} process --subject ${WORK_DIR}/synthetic.toml --in ${WORK_DIR}/bad.c3d
                        --out-bvh ${WORK_DIR}/x.bvh --lookahead abc RESULT_VARIABLE rc ERROR_VARIABLE err)
if(rc EQUAL 0 OR NOT err MATCHES "--lookahead: Failed parsing abc as a INT")
  message(FATAL_ERROR "a lookahead that is no number: rc=${rc} err=${err}")
endif()
execute_process(COMMAND ${MOCAPD} process --subject ${WORK_DIR}/synthetic.toml --in ${WORK_DIR}/bad.c3d
                        --out-bvh ${WORK_DIR}/x.bvh --lookahead 2.5 RESULT_VARIABLE rc ERROR_VARIABLE err)
if(rc EQUAL 0 OR NOT err MATCHES "--lookahead: Failed parsing 2.5 as a INT")
  message(FATAL_ERROR "a lookahead that is no whole number: rc=${rc} err=${err}")
endif()
execute_process(COMMAND ${MOCAP_SIM} synth --humanoid walk --rate fast --out ${WORK_DIR}/fast.c3d
                RESULT_VARIABLE rc ERROR_VARIABLE err)
if(rc EQUAL 0 OR NOT err MATCHES "--rate: Failed parsing fast as a FLOAT")
  message(FATAL_ERROR "a rate that is no number: rc=${rc} err=${err}")
endif()
# nan passes CLI11's number and range checks (every comparison with it is false): it
# ran a one-frame take for --seconds nan and the default rate for --rate nan.
foreach(option IN ITEMS --seconds --rate --noise-mm)
  foreach(value IN ITEMS nan NaN -inf)
    execute_process(COMMAND ${MOCAP_SIM} synth --humanoid walk ${option} ${value} --out ${WORK_DIR}/nan.c3d
                    RESULT_VARIABLE rc ERROR_VARIABLE err)
    if(rc EQUAL 0 OR NOT err MATCHES "${option}: Value ${value} is not a finite number")
      message(FATAL_ERROR "synth ${option} ${value} was not refused: rc=${rc} err=${err}")
    endif()
  endforeach()
endforeach()
execute_process(COMMAND ${MOCAPD} demo --seconds nan RESULT_VARIABLE rc ERROR_VARIABLE err)
if(rc EQUAL 0 OR NOT err MATCHES "--seconds: Value nan is not a finite number")
  message(FATAL_ERROR "demo --seconds nan was not refused: rc=${rc} err=${err}")
endif()
execute_process(COMMAND ${MOCAP_SIM} replay --rate 120x --from "" RESULT_VARIABLE rc ERROR_VARIABLE err)
if(rc EQUAL 0 OR NOT err MATCHES "--rate must be realtime, max or a rate in Hz, got '120x'")
  message(FATAL_ERROR "replay --rate 120x was not refused: rc=${rc} err=${err}")
endif()
# A take of no frames names its file (it said "resample: no frames").
file(WRITE ${WORK_DIR}/no_frames.bvh "HIERARCHY\nROOT Hips\n{\n  OFFSET 0 0 0\n  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation\n  End Site\n  {\n    OFFSET 0 10 0\n  }\n}\nMOTION\nFrames: 0\nFrame Time: 0.0083333\n")
execute_process(COMMAND ${MOCAP_SIM} replay ${WORK_DIR}/no_frames.bvh --rate max --from ""
                RESULT_VARIABLE rc ERROR_VARIABLE err)
if(rc EQUAL 0 OR NOT err MATCHES "no_frames.bvh: the take has no frames")
  message(FATAL_ERROR "replay of a take with no frames: rc=${rc} err=${err}")
endif()
# An empty path was taken as a value: an error that did not name the option (--out-bvh)
# or the option silently ignored (--plot).
foreach(option IN ITEMS --out-bvh --plot --out-c3d --report)
  set(args --subject ${WORK_DIR}/markers_only.toml --in ${WORK_DIR}/pig_bad.c3d)
  if(NOT option STREQUAL "--out-bvh")
    list(APPEND args --out-bvh ${WORK_DIR}/empty.bvh)
  endif()
  execute_process(COMMAND ${MOCAPD} process ${args} ${option} "" RESULT_VARIABLE rc ERROR_VARIABLE err)
  if(rc EQUAL 0 OR NOT err MATCHES "${option}: a path is needed")
    message(FATAL_ERROR "process ${option} \"\" was not refused: rc=${rc} err=${err}")
  endif()
endforeach()
execute_process(COMMAND ${MOCAP_SIM} synth --humanoid walk --out "" RESULT_VARIABLE rc ERROR_VARIABLE err)
if(rc EQUAL 0 OR NOT err MATCHES "--out: a path is needed")
  message(FATAL_ERROR "synth --out \"\" was not refused: rc=${rc} err=${err}")
endif()
# An output that cannot be written is refused before the work: a replay ran to its end
# and then failed to write its report.
execute_process(COMMAND ${MOCAP_SIM} replay --humanoid walk --seconds 1 --rate max --from ""
                        --to tcp://127.0.0.1:1 --report ${WORK_DIR}/missing/r.json
                RESULT_VARIABLE rc OUTPUT_VARIABLE out ERROR_VARIABLE err)
if(rc EQUAL 0 OR NOT err MATCHES "--report ${WORK_DIR}/missing/r.json: the folder ${WORK_DIR}/missing does not exist"
   OR out MATCHES "replaying")
  message(FATAL_ERROR "replay --report in a missing folder was not refused first: rc=${rc} out=${out} err=${err}")
endif()
# An empty input path or endpoint is named as empty ("File does not exist: " named nothing;
# "cannot bind : Invalid argument").
execute_process(COMMAND ${MOCAPD} process --subject "" --in ${WORK_DIR}/pig_bad.c3d --out-bvh ${WORK_DIR}/e.bvh
                RESULT_VARIABLE rc ERROR_VARIABLE err)
if(rc EQUAL 0 OR NOT err MATCHES "--subject: a path is needed")
  message(FATAL_ERROR "process --subject \"\" was not refused as empty: rc=${rc} err=${err}")
endif()
execute_process(COMMAND ${MOCAP_SIM} replay --humanoid walk --to "" --from "" RESULT_VARIABLE rc ERROR_VARIABLE err)
if(rc EQUAL 0 OR NOT err MATCHES "--to: an endpoint is needed")
  message(FATAL_ERROR "replay --to \"\" was not refused as empty: rc=${rc} err=${err}")
endif()
# Units and names checked when the command line is read: an unknown unit was found only
# when its file was read, --truth-units without --truth-bvh was ignored, and an empty
# --actor or --marker-set was taken as not given.
execute_process(COMMAND ${MOCAP_SIM} synth --humanoid walk --bvh-units furlong --out ${WORK_DIR}/u.c3d
                RESULT_VARIABLE rc ERROR_VARIABLE err)
if(rc EQUAL 0 OR NOT err MATCHES "--bvh-units: unknown length unit 'furlong'")
  message(FATAL_ERROR "synth --bvh-units furlong was not refused: rc=${rc} err=${err}")
endif()
execute_process(COMMAND ${MOCAPD} process --subject ${WORK_DIR}/markers_only.toml --in ${WORK_DIR}/pig_bad.c3d
                        --out-bvh ${WORK_DIR}/u.bvh --truth-units mm RESULT_VARIABLE rc ERROR_VARIABLE err)
if(rc EQUAL 0 OR NOT err MATCHES "--truth-units requires --truth-bvh")
  message(FATAL_ERROR "process --truth-units without --truth-bvh was not refused: rc=${rc} err=${err}")
endif()
execute_process(COMMAND ${MOCAPD} calibrate --markers ${WORK_DIR}/rom.c3d --out ${WORK_DIR}/u.toml --actor ""
                RESULT_VARIABLE rc ERROR_VARIABLE err)
if(rc EQUAL 0 OR NOT err MATCHES "--actor: a value is needed")
  message(FATAL_ERROR "calibrate --actor \"\" was not refused: rc=${rc} err=${err}")
endif()
